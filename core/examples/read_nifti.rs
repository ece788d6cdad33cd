//! Times reading a NIfTI file (best of 5): `cargo run --release -p fascicle-core --example read_nifti -- FILE`.
//! Used to choose flate2's backend for `.nii.gz` (docs/benchmarks.md).

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args().nth(1).ok_or("usage: read_nifti FILE")?;
    let mut best = f64::INFINITY;
    let mut n = 0;
    for _ in 0..5 {
        let t = std::time::Instant::now();
        let (v, _) = fascicle_core::io::nifti::read::<f32>(&path)?;
        best = best.min(t.elapsed().as_secs_f64());
        n = v.data.len();
    }
    println!("{path}: {n} values, best of 5 {:.1} ms ({:.0} M values/s)", best * 1e3, n as f64 / best / 1e6);
    Ok(())
}
