//! `fascicle-bench all [--quick] --report DIR`: every suite, one report. Each suite runs as a child process
//! of this binary (`fascicle-bench SUITE --csv DIR/SUITE.csv`); its Markdown table goes into
//! `DIR/benchmarks.md` under a header naming the machine, build profile, adapter and date; each renderer's
//! frame time against error is plotted to `DIR/SUITE.png`. With `--python P` (a Python with DIPY 1.12.1),
//! `bench/compare_dipy.py` times DIPY on the same phantom and the report shows the ratios.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;
use std::process::Command;

use fascicle_core::Error;
use plotters::prelude::*;

/// (suite, quick arguments, full arguments, plot: x column is error (true) or n (false)).
const SUITES: [(&str, Option<bool>); 6] = [
    ("fits", None),
    ("tracking", None),
    ("glyphs", Some(true)),
    ("splats", Some(false)),
    ("volume", Some(true)),
    ("tracts", Some(true)),
];

fn io(path: &Path) -> impl Fn(std::io::Error) -> Error + '_ {
    move |e| Error::Io { path: path.to_path_buf(), source: e }
}

/// One CSV row: method, n, param, frame_ms, error.
#[derive(Clone, Debug)]
struct Row {
    method: String,
    n: String,
    param: String,
    ms: f64,
    error: Option<f64>,
    /// Other columns that split series (l_max).
    extra: String,
}

fn read_csv(path: &Path) -> Vec<Row> {
    let Ok(text) = std::fs::read_to_string(path) else { return vec![] };
    let mut lines = text.lines();
    let Some(head) = lines.next() else { return vec![] };
    let cols: Vec<&str> = head.split(',').collect();
    let at = |name: &str| cols.iter().position(|c| *c == name);
    let l_max = at("l_max");
    let (Some(m), Some(n), Some(p), Some(f), e) = (at("method"), at("n"), at("param"), at("frame_ms"), at("error"))
    else {
        return vec![];
    };
    lines
        .filter_map(|l| {
            let v: Vec<&str> = l.split(',').collect();
            Some(Row {
                method: v.get(m)?.to_string(),
                n: v.get(n)?.to_string(),
                param: v.get(p)?.to_string(),
                ms: v.get(f)?.parse().ok()?,
                error: e.and_then(|e| v.get(e)).and_then(|x| x.parse().ok()),
                extra: l_max.and_then(|k| v.get(k)).map_or(String::new(), |x| format!(" l_max={x}")),
            })
        })
        .collect()
}

/// Frame time (log) against error (log) per (method, n) series, or against n for `by_n`.
fn plot(rows: &[Row], title: &str, by_n: bool, out: &Path) -> Result<(), String> {
    let pts: Vec<(String, f64, f64)> = rows
        .iter()
        .filter_map(|r| {
            let x = if by_n { r.n.split_whitespace().next()?.parse::<f64>().ok()? } else { r.error? };
            // Tract rows also differ by resolution (a "WxH" token in param).
            let res = r
                .param
                .split_whitespace()
                .find(|t| t.contains('x') && t.chars().next().is_some_and(|c| c.is_ascii_digit()));
            let series = match (by_n, res) {
                (true, _) => r.method.clone(),
                (false, Some(res)) => format!("{} n={}{} {res}", r.method, r.n, r.extra),
                (false, None) => format!("{} n={}{}", r.method, r.n, r.extra),
            };
            (x > 0.0 && r.ms > 0.0).then_some((series, x, r.ms))
        })
        .collect();
    if pts.is_empty() {
        return Ok(());
    }
    let (xmin, xmax) = pts.iter().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
    let (ymin, ymax) = pts.iter().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.2), b.max(p.2)));
    let root = BitMapBackend::new(out, (900, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d((xmin * 0.7..xmax * 1.4).log_scale(), (ymin * 0.7..ymax * 1.4).log_scale())
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc(if by_n { "n" } else { "error (suite's unit)" })
        .y_desc("frame time (ms)")
        .draw()
        .map_err(|e| e.to_string())?;
    let mut series: BTreeMap<String, Vec<(f64, f64)>> = BTreeMap::new();
    for (s, x, y) in pts {
        series.entry(s).or_default().push((x, y));
    }
    for (i, (name, mut p)) in series.into_iter().enumerate() {
        p.sort_by(|a, b| a.0.total_cmp(&b.0));
        let c = Palette99::pick(i).to_rgba();
        chart
            .draw_series(LineSeries::new(p.clone(), c.stroke_width(2)))
            .map_err(|e| e.to_string())?
            .label(name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], c.stroke_width(2)));
        chart.draw_series(p.into_iter().map(|q| Circle::new(q, 4, c.filled()))).map_err(|e| e.to_string())?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(|e| e.to_string())?;
    root.present().map_err(|e| e.to_string())
}

/// Plots one CSV (`fascicle-bench plot`).
pub fn plot_csv(csv: &Path, out: &Path, title: &str, by_n: bool) -> Result<(), Error> {
    let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, epaint_default_fonts::UBUNTU_LIGHT);
    let rows = read_csv(csv);
    if rows.is_empty() {
        return Err(Error::Param(format!("{}: no rows with method,n,param,frame_ms,error", csv.display())));
    }
    plot(&rows, title, by_n, out).map_err(Error::Param)
}

/// "YYYY-MM-DD" of now (UTC).
fn today() -> String {
    let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs());
    let [y, m, d] = fascicle_scene::headless::civil_date(secs);
    format!("{y:04}-{m:02}-{d:02}")
}

fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|c| {
            c.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let mem = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|m| m.lines().next().and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok()))
        .map_or(String::new(), |kb| format!(", {:.0} GiB", kb / 1_048_576.0));
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    format!("{cpu}, {threads} threads{mem}")
}

pub fn run(quick: bool, quick_suites: &[String], report: &Path, python: Option<&Path>) -> Result<(), Error> {
    if let Some(bad) = quick_suites.iter().find(|q| !SUITES.iter().any(|(s, _)| s == q)) {
        let names: Vec<&str> = SUITES.iter().map(|(s, _)| *s).collect();
        return Err(Error::Param(format!("--quick-suite {bad}: no such suite (one of {})", names.join(", "))));
    }
    let is_quick = |suite: &str| quick || quick_suites.iter().any(|q| q == suite);
    let mode = match (quick, quick_suites.is_empty()) {
        (true, _) => "--quick".to_string(),
        (false, true) => "full".to_string(),
        (false, false) => format!("full, except --quick for {}", quick_suites.join(", ")),
    };
    let regenerate: String =
        if quick { " --quick".into() } else { quick_suites.iter().map(|q| format!(" --quick-suite {q}")).collect() };
    std::fs::create_dir_all(report).map_err(io(report))?;
    let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, epaint_default_fonts::UBUNTU_LIGHT);
    let exe = std::env::current_exe().map_err(io(report))?;
    let adapter = match std::env::var("VK_ICD_FILENAMES") {
        Ok(v) if v.contains("lvp") => "lavapipe (Mesa software Vulkan)".to_string(),
        Ok(v) => v,
        Err(_) => "the default Vulkan adapter".into(),
    };
    let mut md = String::new();
    let _ = writeln!(md, "# Fascicle benchmarks\n");
    let _ = writeln!(
        md,
        "- machine: {}\n- build: release profile, `fascicle {}`\n- adapter: {adapter}\n- date: {}\n- mode: {}\n",
        machine(),
        env!("CARGO_PKG_VERSION"),
        today(),
        mode
    );
    let _ = writeln!(md, "Regenerate with `fascicle-bench all{regenerate} --report DIR`.\n");
    for (suite, plot_kind) in SUITES {
        let csv = report.join(format!("{suite}.csv"));
        let mut cmd = Command::new(&exe);
        cmd.arg(suite);
        if suite != "tracking" {
            cmd.arg("--csv").arg(&csv);
            // The CPU suite always runs on the full 128x128x64 phantom (about 20 s here).
            if is_quick(suite) && suite != "fits" {
                cmd.arg("--quick");
            }
        }
        if suite == "fits" {
            cmd.arg("--write-phantom").arg(report);
        }
        if suite == "tracking" {
            cmd.args(["--phantom", "data/phantom"]);
            if let Some(py) = python {
                cmd.arg("--python").arg(py);
            }
        }
        eprintln!("bench {suite} ...");
        let out = cmd.output().map_err(io(&exe))?;
        let text = String::from_utf8_lossy(&out.stdout);
        if !out.status.success() {
            let _ = writeln!(
                md,
                "## {suite}\n\nfailed: {}\n",
                String::from_utf8_lossy(&out.stderr).lines().last().unwrap_or("")
            );
            continue;
        }
        let _ = writeln!(md, "{}\n", text.trim());
        if let Some(by_error) = plot_kind {
            let png = report.join(format!("{suite}.png"));
            let title = format!("{suite}: frame time against {}", if by_error { "error" } else { "size" });
            match plot(&read_csv(&csv), &title, !by_error, &png) {
                Ok(()) => {
                    let _ = writeln!(md, "![{suite}]({suite}.png)\n");
                }
                Err(e) => {
                    let _ = writeln!(md, "(plot failed: {e})\n");
                }
            }
        }
    }
    if let Some(py) = python {
        eprintln!("DIPY ...");
        let st = Command::new(py).arg("bench/compare_dipy.py").arg(report).status().map_err(io(py))?;
        if !st.success() {
            let _ = writeln!(md, "DIPY comparison failed (exit {st}).\n");
        }
    }
    let dipy = read_csv(&report.join("dipy.csv"));
    let ours = read_csv(&report.join("fits.csv"));
    if !dipy.is_empty() {
        let _ = writeln!(md, "## Side by side with DIPY 1.12.1 (same files, same machine)\n");
        let _ = writeln!(md, "| operation | DIPY (ms) | Fascicle (ms) | DIPY / Fascicle |\n|---|---|---|---|");
        for d in &dipy {
            if let Some(f) = ours.iter().find(|r| r.method == d.method) {
                let _ = writeln!(md, "| {} | {:.0} | {:.0} | {:.1}x |", d.method, d.ms, f.ms, d.ms / f.ms);
            }
        }
        let _ = writeln!(
            md,
            "\nDIPY's tracking row includes its WLS fit and peak extraction; Fascicle's its WLS fit and tensor field.\n"
        );
    }
    let path = report.join("benchmarks.md");
    std::fs::write(&path, md).map_err(io(&path))?;
    println!("wrote {}", path.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    /// A misspelt `--quick-suite` is refused before any suite runs, naming the choices.
    #[test]
    fn unknown_quick_suite_is_a_clear_error() {
        let dir = std::env::temp_dir().join(format!("fascicle-bench-all-{}", std::process::id()));
        let e = super::run(false, &["glyph".into()], &dir, None).unwrap_err().to_string();
        assert!(e.contains("--quick-suite glyph: no such suite") && e.contains("glyphs"), "{e}");
        assert!(!dir.join("benchmarks.md").exists());
        std::fs::remove_dir_all(dir).ok();
    }
}
