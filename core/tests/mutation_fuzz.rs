//! Deterministic mutation fuzzing of every reader: thousands of truncated, bit-flipped and spliced
//! variants of real files. Each must read or fail with an error; none may panic. (`fuzz/` holds
//! coverage-guided cargo-fuzz targets for longer runs.)

mod common;
use common::data;

use fascicle_core::io::{GradientTable, nifti, tck, trk};
use rand::{RngExt, SeedableRng};

fn mutants(seed: &[u8], n: usize, rng: &mut impl RngExt) -> Vec<Vec<u8>> {
    (0..n)
        .map(|i| {
            let mut b = seed.to_vec();
            match i % 4 {
                0 => b.truncate(rng.random_range(0..=b.len())),
                1 => {
                    for _ in 0..rng.random_range(1..8) {
                        let k = rng.random_range(0..b.len().max(1));
                        if let Some(x) = b.get_mut(k) {
                            *x ^= 1 << rng.random_range(0..8);
                        }
                    }
                }
                2 => {
                    // overwrite a header-sized window with random bytes
                    let k = rng.random_range(0..b.len().clamp(1, 1000));
                    for j in k..(k + 8).min(b.len()) {
                        b[j] = rng.random();
                    }
                }
                _ => {
                    // large integers in likely count/size fields
                    let k = rng.random_range(0..b.len().clamp(1, 1000)) & !3;
                    if k + 4 <= b.len() {
                        b[k..k + 4].copy_from_slice(&[0xff, 0xff, 0xff, 0x7f]);
                    }
                }
            }
            b
        })
        .collect()
}

#[test]
fn readers_never_panic_on_mutated_files() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(2);
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-mut-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    let cases: [(&str, &str); 7] = [
        ("dwi/small_25.nii.gz", "m.nii.gz"),
        ("dwi/qform_be_scaled.nii", "m.nii"),
        ("dwi/small_25_nifti2.nii.gz", "m2.nii.gz"),
        ("tracts/complex.trk", "m.trk"),
        ("tracts/standard.tck", "m.tck"),
        ("tracts/tracks300_f32_deflate.trx", "m.trx"),
        ("dwi/small_25.bvec", "m.bvec"),
    ];
    let mut outcomes = (0usize, 0usize);
    for (src, name) in cases {
        let mut seed = std::fs::read(data(src)).unwrap();
        if src.ends_with(".gz") {
            // mutate the decompressed bytes too, or almost every mutant would only be a gzip error
            seed = nifti_raw(&data(src));
        }
        let p = dir.join(name.trim_end_matches(".gz"));
        for m in mutants(&seed, 1500, &mut rng) {
            std::fs::write(&p, &m).unwrap();
            let ok = match name {
                n if n.contains(".nii") => nifti::read::<f32>(&p).is_ok(),
                // The whole-file and the streaming readers: both answer (an error, never a panic), and where
                // both read the file they read the same streamlines.
                "m.trk" | "m.tck" | "m.trx" => {
                    let whole = match name {
                        "m.trk" => trk::read(&p).map(|(t, _)| t),
                        "m.tck" => tck::read(&p).map(|(t, _)| t),
                        _ => fascicle_core::io::Tractogram::read(&p),
                    };
                    let streamed = streamed(&p);
                    if let (Ok(a), Ok(b)) = (&whole, &streamed) {
                        assert_eq!((&a.offsets, &a.points), (&b.offsets, &b.points), "{name}");
                    }
                    whole.is_ok() && streamed.is_ok()
                }
                _ => GradientTable::from_fsl(data("dwi/small_25.bval"), &p, 50.0).is_ok(),
            };
            if ok { outcomes.0 += 1 } else { outcomes.1 += 1 }
        }
    }
    println!("mutants read: {}, rejected with an error: {}", outcomes.0, outcomes.1);
    assert!(outcomes.1 > 1000, "mutations should mostly be rejected");
}

/// The track value readers (`.tsf`, weights text) on mutants of files written here: an error or values, never
/// a panic.
#[test]
fn track_value_readers_never_panic_on_mutated_files() {
    use fascicle_core::io::{tsf, weights};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
    let tmp_dir = tempfile::Builder::new().prefix("fascicle-mut-values-").tempdir().unwrap();
    let dir = tmp_dir.path().to_path_buf();
    let t = fascicle_core::phantom::whole_brain_streamlines(1, 0, 20);
    let (tsf_path, w_path) = (dir.join("v.tsf"), dir.join("w.txt"));
    tsf::write(&tsf_path, &tsf::TrackScalars::for_tractogram(&t, |i, k| (i * 1000 + k) as f32)).unwrap();
    let ws: Vec<f32> = (0..t.n_streamlines()).map(|i| i as f32 * 0.25).collect();
    weights::write(&w_path, &ws).unwrap();
    let mut outcomes = (0usize, 0usize);
    for p in [&tsf_path, &w_path] {
        let seed = std::fs::read(p).unwrap();
        let m_path = dir.join(format!("m.{}", p.extension().unwrap().to_string_lossy()));
        for m in mutants(&seed, 1500, &mut rng) {
            std::fs::write(&m_path, &m).unwrap();
            let ok = if p == &tsf_path {
                tsf::read(&m_path).map(|s| s.check_against(&t, &m_path).is_ok()).unwrap_or(false)
            } else {
                weights::WeightReader::open(&m_path)
                    .and_then(|mut r| {
                        r.take(t.n_streamlines())?;
                        r.finish(t.n_streamlines() as u64)
                    })
                    .is_ok()
            };
            if ok { outcomes.0 += 1 } else { outcomes.1 += 1 }
        }
    }
    println!("value mutants matching the tractogram: {}, rejected: {}", outcomes.0, outcomes.1);
    assert!(outcomes.0 > 100 && outcomes.1 > 1000, "{outcomes:?}");
}

/// Every streamline of a file through the streaming reader, in small chunks.
fn streamed(p: &std::path::Path) -> fascicle_core::Result<fascicle_core::io::Tractogram> {
    let mut r = fascicle_core::io::stream::TractogramReader::open(p)?;
    let mut all = fascicle_core::io::Tractogram::new();
    while let Some(c) = r.next_chunk(100)? {
        for s in c.iter() {
            all.push(s);
        }
    }
    Ok(all)
}

fn nifti_raw(p: &std::path::Path) -> Vec<u8> {
    use std::io::Read;
    let raw = std::fs::read(p).unwrap();
    let mut out = Vec::new();
    flate2::read::MultiGzDecoder::new(&raw[..]).read_to_end(&mut out).unwrap();
    out
}
