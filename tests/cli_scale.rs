//! Whole-brain scale at a size CI affords: `info`, `select` and `convert` stream a generated tractogram of
//! 100,000 streamlines (10M points, a 120 MB `.tck`) with a peak resident memory far below the file's size
//! (measured from the process by `wait4`), and agree with an in-memory reading of the same file; `render` draws
//! it as a tractogram layer and as a tract layer with an ROI (its streamlines read in place) within a bound. The full
//! sizes (1M and 10M streamlines) are in `fascicle-bench scale`.

use std::path::Path;
use std::process::{Command, Stdio};

use fascicle_core::io::Tractogram;
use fascicle_core::roi::{Criteria, Region, RoiShape};

/// Peak resident memory (MiB) the bound allows any command at this size; the input is 120 MB.
const PEAK_MIB: f64 = 96.0;

/// Peak resident memory (MiB) the bound allows `render` of the file as lines at 640x360.
const RENDER_PEAK_MIB: f64 = 900.0;

/// An 8-bit RGBA PNG: (width, height, pixels).
fn read_png(path: &Path) -> (u32, u32, Vec<u8>) {
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut reader = dec.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgba, "{}", path.display());
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

/// Runs `fascicle ARGS`: its stdout, and its peak resident memory in MiB.
#[allow(clippy::zombie_processes, reason = "the child is reaped by wait4, which also reports its peak memory")]
fn fascicle(args: &[&str]) -> (String, f64) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_fascicle"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run fascicle");
    let mut out = String::new();
    let mut err = String::new();
    std::io::Read::read_to_string(child.stdout.as_mut().unwrap(), &mut out).unwrap();
    std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut err).unwrap();
    let mut status = 0;
    // SAFETY: an all-zero rusage is a valid value; wait4 fills it for our own child.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: waits for the child spawned above (std has not reaped it), writing into locals.
    let pid = unsafe { libc::wait4(child.id() as libc::pid_t, &mut status, 0, &mut usage) };
    assert_eq!(pid, child.id() as libc::pid_t, "wait4");
    assert!(libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0, "fascicle {args:?} failed: {err}");
    (out, usage.ru_maxrss as f64 / 1024.0)
}

/// A folder removed when the test ends, passed or failed (the files it holds at once add up to about 500 MB).
fn scratch() -> tempfile::TempDir {
    tempfile::Builder::new().prefix("fascicle-scale-").tempdir().unwrap()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Writes the generated tractogram when this test binary is run as a helper (`FASCICLE_SCALE_WRITE=path`),
/// so that the measuring process stays small (see below); a no-op otherwise.
#[test]
fn write_helper() {
    if let Some(path) = std::env::var_os("FASCICLE_SCALE_WRITE") {
        fascicle_core::phantom::write_whole_brain(Path::new(&path), 100_000, 11).unwrap();
    }
}

/// The children run before this process reads any file whole, and the input is written by another process: a
/// child's peak (`ru_maxrss`) starts from its parent's high-water mark at the spawn, so a large parent would
/// hide the child's own figure.
#[test]
fn commands_stream_a_large_tractogram_in_bounded_memory() {
    let scratch = scratch();
    let dir = scratch.path();
    let tck = dir.join("brain100k.tck");
    let helper = Command::new(std::env::current_exe().unwrap())
        .args(["--exact", "write_helper", "--quiet"])
        .env("FASCICLE_SCALE_WRITE", &tck)
        .output()
        .unwrap();
    assert!(helper.status.success(), "{helper:?}");
    let bytes = std::fs::metadata(&tck).unwrap().len();
    assert!(bytes > 110_000_000, "the input is {bytes} bytes");
    let (sel, trx, trk) = (dir.join("sel.tck"), dir.join("brain100k.trx"), dir.join("brain100k.trk"));
    let runs: [(&str, Vec<&str>, f64); 5] = [
        ("info", vec!["info", "--json", s(&tck)], PEAK_MIB),
        ("select", vec!["select", s(&tck), "--include", "0,0,0,10", "--out", s(&sel), "--quiet"], PEAK_MIB),
        ("convert tck -> trx", vec!["convert", s(&tck), s(&trx), "--quiet"], PEAK_MIB),
        // A TRX's header and offsets only.
        ("info trx", vec!["info", "--json", s(&trx)], 48.0),
        ("convert trx -> trk", vec!["convert", s(&trx), s(&trk), "--quiet"], PEAK_MIB),
    ];
    let mut outputs = vec![];
    for (what, args, bound) in &runs {
        let (out, peak) = fascicle(args);
        eprintln!("{what}: {peak:.1} MiB");
        assert!(peak < *bound, "{what} of a {bytes}-byte file peaked at {peak:.1} MiB (bound {bound})");
        outputs.push(out);
    }

    // `fascicle view` opens a tractogram as lines: the renderer draws it streamed (10 parts of at most 1M points),
    // compressed, in one frame once loaded. Each part's points are let go once its lines are made; the bound
    // leaves room for the renderer and the software rasteriser (measured 600-700 MiB at 640x360).
    let scene = dir.join("lines.ron");
    let png = dir.join("lines.png");
    std::fs::write(
        &scene,
        format!(
            "(layers: [(name: \"t\", visible: true, opacity: 1.0, kind: Tractogram(path: {:?}))], \
             camera: (eye: (0.0, -330.0, 60.0), target: (0.0, 0.0, 0.0), up: (0.0, 0.0, 1.0), fov_y_deg: 45.0))",
            s(&tck)
        ),
    )
    .unwrap();
    let (_, peak) = if fascicle_render::headless::gpu_tests_skipped() {
        (String::new(), 0.0)
    } else {
        fascicle(&["render", s(&scene), "--out", s(&png), "--size", "640x360", "--quiet"])
    };
    eprintln!("render: {peak:.1} MiB");
    assert!(peak < RENDER_PEAK_MIB, "render of a {bytes}-byte file peaked at {peak:.1} MiB (bound {RENDER_PEAK_MIB})");
    let (w, h, rgba) = if png.is_file() { read_png(&png) } else { (8, 8, vec![0; 256]) };
    // The brain-sized ellipsoid (about 150 x 180 x 120 mm) seen from 330 mm: streamlines cover its middle, the
    // corners are background.
    let px = |x: u32, y: u32| &rgba[4 * (y * w + x) as usize..][..3];
    let background = px(1, 1).to_vec();
    let lit = |x: u32, y: u32| px(x, y).iter().zip(&background).map(|(a, b)| a.abs_diff(*b) as u32).sum::<u32>() > 30;
    let (cx, cy) = (w / 2, h / 2);
    let centre = (cx - 20..cx + 20).flat_map(|x| (cy - 20..cy + 20).map(move |y| (x, y))).filter(|(x, y)| lit(*x, *y));
    assert!(
        fascicle_render::headless::gpu_tests_skipped() || centre.count() > 1500,
        "the centre of the image is not covered by streamlines"
    );
    assert!(!lit(w - 3, 2) && !lit(2, h - 3) && !lit(w - 3, h - 3), "a corner of the image is not background");

    // The same file as a tract layer (the kind ROIs act on) with a 10 mm include sphere 50 mm to the right: its
    // parts read their streamlines in place from the mapped file, so the render stays within the same bound,
    // and the sphere selects among them: the right of the picture stays covered, its far left goes dark.
    let roi_scene = dir.join("roi.ron");
    let roi_png = dir.join("roi.png");
    std::fs::write(
        &roi_scene,
        format!(
            "(layers: [(name: \"t\", visible: true, opacity: 1.0, kind: Tracts(source: File(path: {:?}), mode: \
             Lines, rois: [(shape: Sphere(centre: (50.0, 0.0, 0.0), radius: 10.0), mode: Include)]))], \
             camera: (eye: (0.0, -330.0, 60.0), target: (0.0, 0.0, 0.0), up: (0.0, 0.0, 1.0), fov_y_deg: 45.0))",
            s(&tck)
        ),
    )
    .unwrap();
    if !fascicle_render::headless::gpu_tests_skipped() {
        let (_, roi_peak) = fascicle(&["render", s(&roi_scene), "--out", s(&roi_png), "--size", "640x360", "--quiet"]);
        eprintln!("render of a tract layer with an ROI: {roi_peak:.1} MiB");
        assert!(roi_peak < RENDER_PEAK_MIB, "render with an ROI peaked at {roi_peak:.1} MiB (bound {RENDER_PEAK_MIB})");
        let (rw, rh, roi_rgba) = read_png(&roi_png);
        assert_eq!((rw, rh), (w, h));
        let lit_in = |rgba: &[u8], x: u32, y: u32| {
            let p = &rgba[4 * (y * w + x) as usize..][..3];
            p.iter().zip(&background).map(|(a, b)| a.abs_diff(*b) as u32).sum::<u32>() > 30
        };
        let count = |rgba: &[u8], xs: std::ops::Range<u32>| {
            xs.flat_map(|x| (0..h).map(move |y| (x, y))).filter(|(x, y)| lit_in(rgba, *x, *y)).count()
        };
        // Bands 40 pixels wide at the brain's left and right edges (it spans about 200 pixels about the centre;
        // the sphere lies at the right): the right edge keeps its streamlines, most of the left's go.
        let (left, right) = (cx - 100..cx - 60, cx + 60..cx + 100);
        let (all_left, all_right) = (count(&rgba, left.clone()), count(&rgba, right.clone()));
        let (roi_left, roi_right) = (count(&roi_rgba, left), count(&roi_rgba, right));
        eprintln!(
            "lit pixels at the left / right edges: {all_left} / {all_right}, with the ROI {roi_left} / {roi_right}"
        );
        assert!(
            all_left > 1000 && all_right > 1000,
            "the brain's edges are not where they were: {all_left}, {all_right}"
        );
        assert!(
            roi_left * 2 < all_left,
            "the ROI kept the left edge's streamlines: {roi_left} of {all_left} pixels lit"
        );
        assert!(roi_right * 5 > all_right * 4, "the ROI hid the right edge's streamlines: {roi_right} of {all_right}");
    }

    let whole = Tractogram::read(&tck).unwrap();
    for json in [&outputs[0], &outputs[3]] {
        let v: serde_json::Value = serde_json::from_str(json).unwrap();
        assert_eq!((v["count"].as_u64(), v["points"].as_u64()), (Some(100_000), Some(whole.points.len() as u64)));
    }
    let v: serde_json::Value = serde_json::from_str(&outputs[0]).unwrap();
    let lo = whole.points.iter().copied().reduce(glam::Vec3::min).unwrap();
    assert_eq!(v["bounds"][0], serde_json::json!(lo.to_array()));

    let c = Criteria {
        include: vec![Region::Shape(RoiShape::Sphere { centre: [0.0; 3], radius: 10.0 })],
        ..Default::default()
    };
    let keep: Vec<bool> = whole.iter().map(|s| c.keeps(s)).collect();
    let want = whole.subset(&keep);
    let got = Tractogram::read(&sel).unwrap();
    assert!(want.n_streamlines() > 1000, "{} kept", want.n_streamlines());
    assert_eq!((got.offsets, got.points), (want.offsets, want.points));

    let back = Tractogram::read(&trk).unwrap();
    assert_eq!(back.offsets, whole.offsets);
    let worst = back.points.iter().zip(&whole.points).map(|(a, b)| (*a - *b).abs().max_element()).fold(0.0, f32::max);
    assert!(worst < 1e-4, "points moved by {worst} mm through .trx and .trk");
}
