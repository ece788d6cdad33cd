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
    let dir = std::env::temp_dir().join(format!("fascicle-render-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
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
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn bad_scene_file_is_a_clear_error() {
    let dir = std::env::temp_dir().join(format!("fascicle-badscene-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("bad.ron"), "(layers: [oops])").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_fascicle"))
        .args(["render", dir.join("bad.ron").to_str().unwrap(), "--out", dir.join("x.png").to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.ron") && err.contains("not a scene file"), "{err}");
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn scene_files_round_trip() {
    let s = fascicle::scene::Scene::default_scene();
    let p = std::env::temp_dir().join(format!("fascicle-scene-{}.ron", std::process::id()));
    s.save(&p).unwrap();
    assert_eq!(fascicle::scene::Scene::load(&p).unwrap(), s);
    std::fs::remove_file(p).ok();
}
