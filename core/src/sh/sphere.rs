//! Sample directions on the unit sphere: DIPY's `symmetric362` and `repulsion724` vertex sets, Fibonacci
//! spheres of any size, and a product Gauss-Legendre quadrature exact for polynomials of a given degree.

use glam::DVec3;

const SYMMETRIC362: &str = include_str!("../../data/spheres/symmetric362_vertices.txt");
const REPULSION724: &str = include_str!("../../data/spheres/repulsion724_vertices.txt");

fn parse(text: &str) -> Vec<DVec3> {
    text.lines()
        .filter_map(|l| {
            let v: Vec<f64> = l.split_whitespace().filter_map(|t| t.parse().ok()).collect();
            (v.len() == 3).then(|| DVec3::new(v[0], v[1], v[2]))
        })
        .collect()
}

/// DIPY's `default_sphere` vertices (362 unit vectors, antipodally symmetric).
pub fn symmetric362() -> Vec<DVec3> {
    parse(SYMMETRIC362)
}

/// DIPY's `repulsion724` vertices.
pub fn repulsion724() -> Vec<DVec3> {
    parse(REPULSION724)
}

/// `n` nearly uniform unit vectors on a golden-angle spiral.
pub fn fibonacci(n: usize) -> Vec<DVec3> {
    let ga = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let z = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
            let r = (1.0 - z * z).max(0.0).sqrt();
            let phi = ga * i as f64;
            DVec3::new(r * phi.cos(), r * phi.sin(), z)
        })
        .collect()
}

/// Gauss-Legendre nodes and weights on [-1, 1] (Newton on the Legendre recurrence).
pub fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    let (mut x, mut w) = (vec![0.0; n], vec![0.0; n]);
    for i in 0..n.div_ceil(2) {
        let mut z = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
        let mut pp = 1.0;
        for _ in 0..100 {
            let (mut p1, mut p2) = (1.0f64, 0.0f64);
            for j in 1..=n {
                let p3 = p2;
                p2 = p1;
                p1 = ((2 * j - 1) as f64 * z * p2 - (j - 1) as f64 * p3) / j as f64;
            }
            pp = n as f64 * (z * p1 - p2) / (z * z - 1.0);
            let z1 = z;
            z = z1 - p1 / pp;
            if (z - z1).abs() < 1e-15 {
                break;
            }
        }
        x[i] = -z;
        x[n - 1 - i] = z;
        w[i] = 2.0 / ((1.0 - z * z) * pp * pp);
        w[n - 1 - i] = w[i];
    }
    (x, w)
}

/// A quadrature on the sphere exact for polynomials up to degree `deg`: Gauss-Legendre in cos θ times
/// uniform φ. Returns directions and weights summing to 4π.
pub fn quadrature(deg: usize) -> (Vec<DVec3>, Vec<f64>) {
    let nt = deg / 2 + 1;
    let np = deg + 1;
    let (xs, ws) = gauss_legendre(nt);
    let mut dirs = Vec::with_capacity(nt * np);
    let mut wts = Vec::with_capacity(nt * np);
    for (z, wz) in xs.iter().zip(&ws) {
        let r = (1.0 - z * z).max(0.0).sqrt();
        for k in 0..np {
            let phi = 2.0 * std::f64::consts::PI * k as f64 / np as f64;
            dirs.push(DVec3::new(r * phi.cos(), r * phi.sin(), *z));
            wts.push(wz * 2.0 * std::f64::consts::PI / np as f64);
        }
    }
    (dirs, wts)
}
