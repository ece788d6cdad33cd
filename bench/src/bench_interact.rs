//! `fascicle-bench interact`: the real viewer window (winit, on Xvfb when there is no display), driven through
//! the window system's event path by `xdotool`: per scene, its opening, an orbit (a left drag over the 3D
//! view), a hover (the pointer crossing the still 3D view, no button), an ROI drag (Shift + left drag from the
//! first ROI sphere), then the idle window.
//!
//! The viewer writes a line per frame to the file named by `FASCICLE_FRAME_LOG` (wall clock, the frame's time
//! as the panel's readout shows it, the render scale, the ROI's window position, the ROI selections made so
//! far). Per action: the ROI selections that landed from the press until the picture settled; the frames drawn
//! between the press and the release (a hover: its first and last move), each timed from the frame before (the wall clock of the lines: the
//! readout's time comes from the render world, a frame late under pipelined rendering), their median and
//! 95th percentile; `refine_ms`, from the release until the process stops using the CPU (the
//! full-quality frame drawn, read from `/proc/PID/stat` every 10 ms until 600 ms pass without a tick); and for
//! the idle row, the CPU the process uses over 10 s once settled, in % of one core. The `open` row: the frames
//! from the first to the one that settles the opened scene, and in `refine_ms` the time from the launch until
//! the process last used the CPU before it went idle: the complete picture drawn and the background work done
//! (a tract layer's ROI indexes are built at the lowest priority after its picture, so there it is later than
//! the picture). Not the frame log's last line: on a software adapter the drawing runs seconds behind the
//! frame's update (a 1M-streamline file's last frame is logged about 6 s before lavapipe has drawn it; the
//! screen, grabbed every 250 ms, settles when the process goes quiet).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

/// The CSV's header (one row per scene and action).
pub const CSV_HEADER: &str = "scene,action,frames,median_ms,p95_ms,refine_ms,idle_cpu_pct,selections";

/// What to run.
pub struct InteractOptions<'a> {
    /// Scenes: `default` (the viewer's own), `large` (`bench edits`' large scene: 1M streamlines, 22.5k order-8
    /// glyphs, a 256³ volume), or a file the viewer opens (a scene, a tractogram, an image).
    pub scenes: &'a [String],
    /// Where `large`'s files are written once.
    pub data: &'a Path,
    /// The window's size, WxH.
    pub size: (u32, u32),
    /// Also write the rows as CSV ([`CSV_HEADER`]).
    pub csv: Option<&'a Path>,
    /// How long a scene may take to load and settle.
    pub settle_timeout: Duration,
    /// The time between two pointer moves of a drag or a hover (33 ms: a mouse at 30 Hz). Frames faster than
    /// this are paced by the input, not by their cost: on a hardware GPU give a few ms, so that the frame times
    /// measured are what the frames cost.
    pub move_interval: Duration,
}

/// One measured action.
struct Row {
    scene: String,
    action: &'static str,
    frames: usize,
    median_ms: f64,
    p95_ms: f64,
    refine_ms: Option<f64>,
    idle_cpu_pct: Option<f64>,
    /// The median render scale of the frames (for the printed table).
    scale: f64,
    /// ROI selections that landed during the action (a drag's steps), from the frame log.
    selections: Option<u64>,
}

impl Row {
    /// A row of frames: `ms`, the times between them (ms), and `scales`, the render scale of each frame counted
    /// (one more than `ms` when the first frame has no interval): their count, the median and 95th percentile
    /// time and the median scale.
    fn of_frames(
        scene: &str,
        action: &'static str,
        mut ms: Vec<f64>,
        mut scales: Vec<f64>,
        refine_ms: Option<f64>,
    ) -> Row {
        ms.sort_by(f64::total_cmp);
        scales.sort_by(f64::total_cmp);
        Row {
            scene: scene.into(),
            action,
            frames: scales.len(),
            median_ms: percentile(&ms, 0.5),
            p95_ms: percentile(&ms, 0.95),
            refine_ms,
            idle_cpu_pct: None,
            scale: percentile(&scales, 0.5),
            selections: None,
        }
    }

    /// The row's fields: for the printed table (with the render scale, fewer digits), or for the CSV
    /// ([`CSV_HEADER`]); a figure the row does not have is empty.
    fn fields(&self, table: bool) -> Vec<String> {
        let num = |v: f64, digits: usize| if v.is_finite() { format!("{v:.digits$}") } else { String::new() };
        let opt = |v: Option<f64>, digits: usize| num(v.unwrap_or(f64::NAN), digits);
        let d = usize::from(!table);
        let mut f = vec![self.scene.clone(), self.action.to_string(), self.frames.to_string()];
        f.extend([num(self.median_ms, 1 + d), num(self.p95_ms, 1 + d)]);
        if table {
            f.push(num(self.scale, 3));
        }
        f.extend([opt(self.refine_ms, d), opt(self.idle_cpu_pct, 2 + d)]);
        f.push(self.selections.map_or(String::new(), |n| n.to_string()));
        f
    }
}

/// Xvfb started by the bench, stopped when dropped.
struct Display(Option<Child>);

impl Drop for Display {
    fn drop(&mut self) {
        if let Some(mut c) = self.0.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// The viewer, killed when dropped.
struct Viewer {
    child: Child,
    log: PathBuf,
}

impl Drop for Viewer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A frame-log line: wall clock (ms), render scale, next frame, ROI position (the readout's frame time and
/// whether the view moved are not used).
struct Frame {
    at_ms: u128,
    scale: f64,
    next: String,
    roi: Option<(f64, f64)>,
    /// ROI selections made so far (the log's ninth column, when there).
    selections: Option<u64>,
}

fn read_log(path: &Path) -> Vec<Frame> {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    text.lines()
        .filter_map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            if f.len() < 7 {
                return None;
            }
            let (x, y) = (f[5].parse::<f64>().ok()?, f[6].parse::<f64>().ok()?);
            Some(Frame {
                at_ms: f[0].parse().ok()?,
                scale: f[2].parse().ok()?,
                next: f[4].to_string(),
                roi: (x.is_finite() && y.is_finite()).then_some((x, y)),
                selections: f.get(8).and_then(|n| n.parse().ok()),
            })
        })
        .collect()
}

fn now_ms() -> u128 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_millis())
}

/// The process's CPU time so far (user + system, all threads), in clock ticks.
fn cpu_ticks(pid: u32) -> Option<u64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // Fields after the command name (which may hold spaces), from the third: utime is the 14th, stime the 15th.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    Some(f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?)
}

fn ticks_per_second() -> f64 {
    // SAFETY: sysconf has no preconditions.
    let t = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    if t > 0 { t as f64 } else { 100.0 }
}

/// Waits until the process has used no CPU for `quiet`; returns when it last did (or None on timeout).
fn wait_quiet(pid: u32, quiet: Duration, timeout: Duration) -> Option<Instant> {
    let start = Instant::now();
    let mut last = cpu_ticks(pid)?;
    let mut last_busy = Instant::now();
    while start.elapsed() < timeout {
        std::thread::sleep(Duration::from_millis(10));
        let t = cpu_ticks(pid)?;
        if t != last {
            last = t;
            last_busy = Instant::now();
        } else if last_busy.elapsed() >= quiet {
            return Some(last_busy);
        }
    }
    None
}

fn which(name: &str) -> Option<PathBuf> {
    std::env::var_os("PATH")?.to_str()?.split(':').map(|d| Path::new(d).join(name)).find(|p| p.is_file())
}

/// The display to use: `$DISPLAY`, else an Xvfb the bench starts (on the first free number from 90).
fn display(size: (u32, u32)) -> Result<(String, Display), String> {
    if let Ok(d) = std::env::var("DISPLAY")
        && !d.is_empty()
    {
        return Ok((d, Display(None)));
    }
    let xvfb = which("Xvfb").ok_or("no $DISPLAY and no Xvfb (apt-get install xvfb, or bench/install_peers.sh)")?;
    let n = (90..200).find(|n| !Path::new(&format!("/tmp/.X11-unix/X{n}")).exists()).ok_or("no free display")?;
    let screen = format!("{}x{}x24", size.0, size.1);
    let child = Command::new(xvfb)
        .args([format!(":{n}"), "-screen".into(), "0".into(), screen, "-nolisten".into(), "tcp".into()])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .map_err(|e| format!("Xvfb: {e}"))?;
    let guard = Display(Some(child));
    let start = Instant::now();
    while !Path::new(&format!("/tmp/.X11-unix/X{n}")).exists() {
        if start.elapsed() > Duration::from_secs(10) {
            return Err("Xvfb did not start within 10 s".into());
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    Ok((format!(":{n}"), guard))
}

/// Runs an xdotool script (commands one per line) on `display`.
fn xdotool(display: &str, script: &str) -> Result<(), String> {
    let mut child = Command::new("xdotool")
        .arg("-")
        .env("DISPLAY", display)
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .map_err(|e| format!("xdotool: {e} (apt-get install xdotool, or bench/install_peers.sh)"))?;
    child.stdin.take().ok_or("xdotool's stdin")?.write_all(script.as_bytes()).map_err(|e| e.to_string())?;
    let status = child.wait().map_err(|e| e.to_string())?;
    if !status.success() {
        return Err(format!("xdotool failed ({status})"));
    }
    Ok(())
}

/// A drag from where the pointer is: `steps` moves of (dx, dy) pixels, one every `every`, with Shift held when
/// `shift`.
fn drag_script((dx, dy): (i32, i32), steps: usize, every: Duration, shift: bool) -> String {
    let mut s = String::new();
    if shift {
        s += "keydown shift\n";
    }
    s += "mousedown 1\n";
    s += &hover_script((dx, dy), steps, every);
    s += "mouseup 1\n";
    if shift {
        s += "keyup shift\n";
    }
    s
}

/// Gives the keyboard focus to the viewer's window (found by its process id).
fn focus_viewer(display: &str, pid: u32) -> Result<(), String> {
    let out = Command::new("xdotool")
        .args(["search", "--sync", "--pid", &pid.to_string(), "--name", "Fascicle", "windowfocus", "--sync"])
        .env("DISPLAY", display)
        .output()
        .map_err(|e| format!("xdotool: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!("xdotool could not focus the viewer's window: {}", String::from_utf8_lossy(&out.stderr)))
    }
}

/// Pointer moves with no button held: `steps` moves of (dx, dy) pixels, one every `every`.
fn hover_script((dx, dy): (i32, i32), steps: usize, every: Duration) -> String {
    let pause = every.as_secs_f64();
    (0..steps).map(|_| format!("mousemove_relative -- {dx} {dy}\nsleep {pause:.4}\n")).collect()
}

pub(crate) fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let i = ((p * (sorted.len() - 1) as f64).round() as usize).min(sorted.len() - 1);
    sorted[i]
}

/// Waits until the viewer has loaded and gone idle (its last frame says `Idle`, and it stays so for a second);
/// returns when the process last used the CPU.
fn wait_settled(viewer: &mut Viewer, timeout: Duration) -> Result<Instant, String> {
    let start = Instant::now();
    loop {
        if let Ok(Some(status)) = viewer.child.try_wait() {
            return Err(format!("the viewer exited ({status})"));
        }
        let frames = read_log(&viewer.log);
        if frames.last().is_some_and(|f| f.next == "Idle")
            && let Some(quiet) = wait_quiet(viewer.child.id(), Duration::from_secs(1), Duration::from_secs(30))
            && read_log(&viewer.log).len() == frames.len()
        {
            return Ok(quiet);
        }
        if start.elapsed() > timeout {
            return Err(format!("the scene did not settle within {} s", timeout.as_secs()));
        }
        std::thread::sleep(Duration::from_millis(500));
    }
}

/// The opening of a scene: its frames (each timed from the one before) and, in `refine_ms`, the time from the
/// launch to `drawn`, the process's last use of the CPU before it went idle (the complete picture drawn, and
/// any background work done).
fn open_row(scene: &str, frames: &[Frame], drawn: Duration) -> Row {
    // Every frame counts, the first (which has no interval) included.
    let ms = frames.windows(2).map(|w| (w[1].at_ms - w[0].at_ms) as f64).collect();
    let scales = frames.iter().map(|f| f.scale).collect();
    Row::of_frames(scene, "open", ms, scales, Some(drawn.as_secs_f64() * 1e3))
}

/// Moves the pointer to (x, y), waits for the frames that draws to pass (a pointer move redraws the window),
/// then plays a drag and measures it.
fn measure_drag(
    scene: &str,
    action: &'static str,
    viewer: &mut Viewer,
    display: &str,
    (x, y): (f64, f64),
    script: &str,
    settle: Duration,
) -> Result<Row, String> {
    xdotool(display, &format!("mousemove {x:.0} {y:.0}\n"))?;
    wait_settled(viewer, settle)?;
    let press = now_ms();
    xdotool(display, script)?;
    let release = now_ms();
    let released = Instant::now();
    let quiet = wait_quiet(viewer.child.id(), Duration::from_millis(600), Duration::from_secs(120));
    let refine_ms = quiet.map(|t| t.saturating_duration_since(released).as_secs_f64() * 1e3);
    let frames = read_log(&viewer.log);
    // A frame's time is the wall time between it and the frame before (both logged at the end of their
    // update); the first frame after the press follows the idle wait and is left out.
    let during: Vec<(f64, f64)> = frames
        .windows(2)
        .filter(|w| w[1].at_ms >= press && w[1].at_ms <= release + 20 && w[0].at_ms >= press)
        .map(|w| ((w[1].at_ms - w[0].at_ms) as f64, w[1].scale))
        .collect();
    let (ms, scales) = during.into_iter().unzip();
    // The selections that landed from the press until the picture settled (the last ones after the release).
    let made = |f: &Frame| f.selections;
    let before = frames.iter().rev().find(|f| f.at_ms < press).and_then(made);
    let selections = frames.last().and_then(made).zip(before).map(|(end, start)| end.saturating_sub(start));
    Ok(Row { selections, ..Row::of_frames(scene, action, ms, scales, refine_ms) })
}

/// The bench (see the module docs).
pub fn run(o: InteractOptions) -> Result<(), String> {
    let exe = std::env::current_exe()
        .ok()
        .and_then(|p| p.parent().map(|d| d.join("fascicle")))
        .filter(|p| p.is_file())
        .ok_or("the fascicle binary is not beside fascicle-bench (cargo build --release)")?;
    which("xdotool").ok_or("xdotool is not installed (apt-get install xdotool, or bench/install_peers.sh)")?;
    let (display, _xvfb) = display(o.size)?;
    let tmp = std::env::temp_dir().join(format!("fascicle-interact-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).map_err(|e| format!("{}: {e}", tmp.display()))?;
    let mut rows = vec![];
    for scene in o.scenes {
        let args: Vec<PathBuf> = match scene.as_str() {
            "default" => vec![],
            "large" => {
                let mut large = crate::bench_edits::large_scene(o.data)?;
                large.layers.push(crate::bench_edits::seeded_tracking());
                let path = o.data.join("large.ron");
                large.save(&path)?;
                vec![path]
            }
            file => vec![PathBuf::from(file)],
        };
        let name = Path::new(scene).file_name().map_or(scene.clone(), |n| n.to_string_lossy().into_owned());
        let log = tmp.join(format!("{name}.frames"));
        let out = std::fs::File::create(tmp.join(format!("{name}.log"))).map_err(|e| e.to_string())?;
        eprintln!("{name}: opening in the viewer ({display}, {}x{}) ...", o.size.0, o.size.1);
        let opened = Instant::now();
        let child = Command::new(&exe)
            .arg("view")
            .args(&args)
            .env("DISPLAY", &display)
            .env("FASCICLE_FRAME_LOG", &log)
            .stdout(out.try_clone().map_err(|e| e.to_string())?)
            .stderr(out)
            .spawn()
            .map_err(|e| format!("{}: {e}", exe.display()))?;
        let mut viewer = Viewer { child, log };
        let drawn = wait_settled(&mut viewer, o.settle_timeout)?;
        eprintln!("  settled after {:.1} s", opened.elapsed().as_secs_f64());
        rows.push(open_row(&name, &read_log(&viewer.log), drawn.saturating_duration_since(opened)));
        // Keys go to the focused window: an Xvfb without a window manager focuses none, and the ROI drag's
        // Shift would never reach the viewer (the drag would orbit instead).
        focus_viewer(&display, viewer.child.id())?;
        // The 3D view is the window right of the panel (about 300 px): orbit from its middle.
        let (cx, cy) = (0.6 * o.size.0 as f64, 0.5 * o.size.1 as f64);
        let orbit = drag_script((6, 0), 60, o.move_interval, false);
        rows.push(measure_drag(&name, "orbit", &mut viewer, &display, (cx, cy), &orbit, o.settle_timeout)?);
        wait_settled(&mut viewer, o.settle_timeout)?;
        // The pointer crossing the still view: every move is a frame (egui's hover), the scene unchanged.
        let hover = hover_script((4, 2), 60, o.move_interval);
        rows.push(measure_drag(
            &name,
            "hover",
            &mut viewer,
            &display,
            (cx - 120.0, cy - 60.0),
            &hover,
            o.settle_timeout,
        )?);
        wait_settled(&mut viewer, o.settle_timeout)?;
        match read_log(&viewer.log).last().and_then(|f| f.roi) {
            Some(at) => {
                let drag = drag_script((0, 2), 60, o.move_interval, true);
                rows.push(measure_drag(&name, "roi_drag", &mut viewer, &display, at, &drag, o.settle_timeout)?);
                wait_settled(&mut viewer, o.settle_timeout)?;
            }
            None => eprintln!("  no ROI sphere in view: no roi_drag row"),
        }
        let (before, t0) = (read_log(&viewer.log).len(), cpu_ticks(viewer.child.id()).ok_or("the viewer's CPU time")?);
        let start = Instant::now();
        std::thread::sleep(Duration::from_secs(10));
        let ticks = cpu_ticks(viewer.child.id()).ok_or("the viewer's CPU time")? - t0;
        let idle_pct = 100.0 * ticks as f64 / ticks_per_second() / start.elapsed().as_secs_f64();
        let frames = read_log(&viewer.log).len() - before;
        rows.push(Row {
            scene: name.clone(),
            action: "idle",
            frames,
            median_ms: f64::NAN,
            p95_ms: f64::NAN,
            refine_ms: None,
            idle_cpu_pct: Some(idle_pct),
            scale: f64::NAN,
            selections: None,
        });
        for r in rows.iter().filter(|r| r.scene == name) {
            eprintln!(
                "  {:9} {:4} frames, median {:7.1} ms, p95 {:7.1} ms, scale {:.3}, refine {:?} ms, idle {:?} %, \
                 selections {:?}",
                r.action, r.frames, r.median_ms, r.p95_ms, r.scale, r.refine_ms, r.idle_cpu_pct, r.selections
            );
        }
    }
    println!(
        "| scene | action | frames | median ms | p95 ms | render scale (median) | refine ms | idle CPU % | selections |\n\
         |---|---|---:|---:|---:|---:|---:|---:|---:|"
    );
    for r in &rows {
        println!("| {} |", r.fields(true).join(" | "));
    }
    if let Some(p) = o.csv {
        let mut f = std::fs::File::create(p).map_err(|e| format!("{}: {e}", p.display()))?;
        writeln!(f, "{CSV_HEADER}").map_err(|e| e.to_string())?;
        for r in &rows {
            writeln!(f, "{}", r.fields(false).join(",")).map_err(|e| e.to_string())?;
        }
    }
    eprintln!("frame logs and the viewer's output: {}", tmp.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_log_lines_and_percentiles() {
        let dir = std::env::temp_dir().join(format!("fascicle-interact-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let p = dir.join("frames");
        std::fs::write(
            &p,
            "1700000000000 12.50 0.5 true Now 640 360\n1700000000100 3.00 1 false Idle NaN NaN false 7\nbad\n",
        )
        .expect("write");
        let f = read_log(&p);
        assert_eq!(f.len(), 2);
        assert_eq!((f[0].at_ms, f[0].scale, f[0].roi), (1700000000000, 0.5, Some((640.0, 360.0))));
        assert_eq!((f[1].next.as_str(), f[1].roi), ("Idle", None));
        assert_eq!((f[0].selections, f[1].selections), (None, Some(7)));
        let _ = std::fs::remove_dir_all(&dir);
        let v: Vec<f64> = (1..=20).map(f64::from).collect();
        assert_eq!((percentile(&v, 0.5), percentile(&v, 0.95)), (11.0, 19.0));
        assert!(cpu_ticks(std::process::id()).is_some());
        let row = Row {
            scene: "default".into(),
            action: "idle",
            frames: 0,
            median_ms: f64::NAN,
            p95_ms: f64::NAN,
            refine_ms: None,
            idle_cpu_pct: Some(0.25),
            scale: f64::NAN,
            selections: None,
        };
        assert_eq!(row.fields(false).join(","), "default,idle,0,,,,0.250,");
        assert_eq!(row.fields(false).len(), CSV_HEADER.split(',').count());
        assert_eq!(row.fields(true).len(), 9);
        // The opening: its frames' intervals, and the time to the complete picture in refine_ms.
        let at = |ms: u128| Frame {
            at_ms: 1_700_000_000_000 + ms,
            scale: 1.0,
            next: "Poll".into(),
            roi: None,
            selections: None,
        };
        let open = open_row("f.tck", &[at(0), at(100), at(400)], Duration::from_millis(5200));
        assert_eq!(open.fields(false).join(","), "f.tck,open,3,300.00,300.00,5200.0,,");
    }
}
