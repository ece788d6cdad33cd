//! `fascicle render` end to end: the default scene gives a PNG of the requested size, the same bytes on a
//! second run, with the phantom visible (not just the clear colour).

use std::process::Command;

fn render(out: &std::path::Path, size: &str) {
    let st = Command::new(env!("CARGO_BIN_EXE_fascicle"))
        .args(["render", "--out", out.to_str().unwrap(), "--size", size])
        .status()
        .expect("run fascicle");
    assert!(st.success(), "fascicle render failed");
}

fn decode(bytes: &[u8]) -> (u32, u32, Vec<u8>) {
    let dec = png::Decoder::new(std::io::Cursor::new(bytes));
    let mut r = dec.read_info().expect("png header");
    let mut buf = vec![0; r.output_buffer_size().expect("size")];
    let info = r.next_frame(&mut buf).expect("png data");
    (info.width, info.height, buf[..info.buffer_size()].to_vec())
}

#[test]
fn default_scene_renders_deterministically() {
    if fascicle_render::headless::gpu_tests_skipped() {
        eprintln!("FASCICLE_SKIP_GPU=1: GPU test skipped");
        return;
    }
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-render-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    let (a, b) = (dir.join("a.png"), dir.join("b.png"));
    render(&a, "200x150");
    render(&b, "200x150");
    let (ba, bb) = (std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    assert_eq!(ba, bb, "two renders of the same scene differ");
    let (w, h, px) = decode(&ba);
    assert_eq!((w, h), (200, 150));
    // The phantom's high-FA ring is white (FA ~0.8 maps to grey ~204 and above); the background and
    // low-FA voxels are dark. Both must be present in quantity.
    let bright = px.chunks(4).filter(|p| p[0] > 180 && p[1] > 180 && p[2] > 180).count();
    let dark = px.chunks(4).filter(|p| p[0] < 60).count();
    assert!(bright > 300 && dark > 10000, "bright {bright}, dark {dark}");
}

#[test]
fn bad_scene_file_is_a_clear_error() {
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-badscene-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    std::fs::write(dir.join("bad.ron"), "(layers: [oops])").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_fascicle"))
        .args(["render", dir.join("bad.ron").to_str().unwrap(), "--out", dir.join("x.png").to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.ron") && err.contains("not a scene file"), "{err}");
}

#[test]
fn scene_files_round_trip() {
    let s = fascicle_scene::model::Scene::default_scene();
    let tmp_p = tempfile::tempdir().unwrap();
    let p = tmp_p.path().join("fascicle-scene.ron");
    s.save(&p).unwrap();
    assert_eq!(fascicle_scene::model::Scene::load(&p).unwrap(), s);
    std::fs::remove_file(p).ok();
}

/// `--depth`: an axial slice (world z = 1 mm, the phantom's slice 12 of 24 at 2 mm) seen straight down from
/// z = 200 lies at view depth 199 mm on every pixel it covers, and its footprint is the projected 96 mm square.
#[test]
fn depth_export_matches_the_slice_plane() {
    if fascicle_render::headless::gpu_tests_skipped() {
        eprintln!("FASCICLE_SKIP_GPU=1: GPU test skipped");
        return;
    }
    use fascicle_scene::model::{CameraSpec, Scene};
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-depth-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    let mut scene = Scene::default_scene();
    scene.layers.truncate(1); // the axial slice only
    scene.camera = CameraSpec { eye: [0.0, 0.0, 200.0], target: [0.0, 0.0, 0.0], up: [0.0, 1.0, 0.0], fov_y_deg: 45.0 };
    let scene_path = dir.join("top.ron");
    scene.save(&scene_path).unwrap();
    let (w, h) = (64usize, 48usize);
    for depth_file in ["d.npy", "d.png"] {
        let st = Command::new(env!("CARGO_BIN_EXE_fascicle"))
            .args(["render", scene_path.to_str().unwrap(), "--size", "64x48", "--force"])
            .args(["--out", dir.join("c.png").to_str().unwrap(), "--depth", dir.join(depth_file).to_str().unwrap()])
            .status()
            .unwrap();
        assert!(st.success());
    }
    let bytes = std::fs::read(dir.join("d.npy")).unwrap();
    let f = npyz::NpyFile::new(&bytes[..]).unwrap();
    assert_eq!(f.shape(), &[h as u64, w as u64]);
    let z: Vec<f32> = f.into_vec().unwrap();
    let covered: Vec<bool> = z.iter().map(|d| d.is_finite()).collect();
    for d in z.iter().filter(|d| d.is_finite()) {
        assert!((d - 199.0).abs() < 1e-2, "view depth {d}, expected 199");
    }
    // Half-size 48 mm at 199 mm with a 45 degree vertical field: 48 * 0.5826 = 27.97 rows, and as many
    // columns (64x48 keeps pixels square): ~782 pixels, give or take the edge rows and columns.
    let n = covered.iter().filter(|c| **c).count();
    assert!((n as i64 - 782).abs() <= 60, "{n} pixels covered");
    let (_, _, png16) = decode(&std::fs::read(dir.join("d.png")).unwrap());
    assert_eq!(png16.len(), 2 * w * h);
    let expected = (0.5f64 / 199.0 * 65535.0).round() as i32; // reverse-Z NDC = near / depth, near 0.5
    for (i, c) in covered.iter().enumerate() {
        let v = u16::from_be_bytes([png16[2 * i], png16[2 * i + 1]]) as i32;
        if *c {
            assert!((v - expected).abs() <= 1, "pixel {i}: {v} vs {expected}");
        } else {
            assert_eq!(v, 0, "pixel {i}: background depth {v}");
        }
    }
}

/// The seed's 50-tensor spiral scene renders: lit barycentric splats, green (linear) at one end of the
/// helix and red (spherical) at the other.
#[test]
fn spiral_scene_renders() {
    if fascicle_render::headless::gpu_tests_skipped() {
        eprintln!("FASCICLE_SKIP_GPU=1: GPU test skipped");
        return;
    }
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-spiral-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    let out = dir.join("spiral.png");
    let scene = format!(
        "{}/scenes/spiral50.ron",
        std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into())
    );
    let st = Command::new(env!("CARGO_BIN_EXE_fascicle"))
        .args(["render", &scene, "--out", out.to_str().unwrap(), "--size", "320x240"])
        .status()
        .expect("run fascicle");
    assert!(st.success());
    let (_, _, px) = decode(&std::fs::read(&out).unwrap());
    let rgb = |p: &[u8]| (p[0] as i32, p[1] as i32, p[2] as i32);
    let green = px.chunks(4).map(rgb).filter(|&(r, g, b)| g > 70 && g > r + 5 && g > b + 30).count();
    let red = px.chunks(4).map(rgb).filter(|&(r, g, b)| r > 60 && r > g + 15 && r > b + 15).count();
    println!("green {green}, red {red}");
    assert!(green > 50 && red > 50, "green {green}, red {red}");
}
