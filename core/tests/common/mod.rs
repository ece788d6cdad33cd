//! Shared helpers of the core tests: paths into the repository's `data/` and `.npy` loading.
#![allow(dead_code, reason = "each test binary uses a different subset")]

use std::path::PathBuf;

pub fn data(rel: &str) -> PathBuf {
    PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()))
        .join("../data")
        .join(rel)
}

/// A float64 `.npy` array: (shape, C-order values).
pub fn npy(rel: &str) -> (Vec<usize>, Vec<f64>) {
    let bytes = std::fs::read(data(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"));
    let f = npyz::NpyFile::new(&bytes[..]).expect("npy header");
    let shape: Vec<usize> = f.shape().iter().map(|&d| d as usize).collect();
    assert!(!f.header().order().eq(&npyz::Order::Fortran), "{rel}: expected C order");
    (shape, f.into_vec::<f64>().expect("f64 npy"))
}

/// C-order flat index of (x, y, z) in an array of leading shape (X, Y, Z, ...) with `inner` trailing values.
pub fn c_index(shape: &[usize], x: usize, y: usize, z: usize) -> usize {
    let inner: usize = shape[3..].iter().product();
    ((x * shape[1] + y) * shape[2] + z) * inner
}
