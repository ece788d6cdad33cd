//! A deterministic synthetic tensor field: the ring + crossing bundle of `data/phantom` (a ring around the
//! volume's z axis crossing a straight bundle along z, isotropic background), built from the tensor model
//! without noise, so the viewer and `fascicle render` need no files.

use glam::{DMat4, DVec3, DVec4};

use crate::dti::eigen::{Eigen, LowerTri, from_eigen};
use crate::dti::metrics;
use crate::volume::Volume;

/// Fibre eigenvalues (mm²/s) and the isotropic background diffusivity.
pub const FIBRE_EVALS: [f64; 3] = [1.7e-3, 0.3e-3, 0.3e-3];
pub const BACKGROUND_MD: f64 = 0.8e-3;

/// The phantom's tensors and the true fibre directions per voxel (voxel axes).
pub struct Phantom {
    pub dims: [usize; 3],
    pub world_from_voxel: DMat4,
    pub tensors: Vec<LowerTri>,
    pub fibres: Vec<Vec<DVec3>>,
}

fn fibre_tensor(dir: DVec3) -> LowerTri {
    let e1 = dir.normalize();
    let e2 = e1.any_orthonormal_vector();
    from_eigen(&Eigen { values: FIBRE_EVALS, vectors: [e1, e2, e1.cross(e2)] })
}

/// The mean of the fibres' tensors in a voxel; the isotropic background where there is none.
fn voxel_tensor(dirs: &[DVec3]) -> LowerTri {
    if dirs.is_empty() {
        return [BACKGROUND_MD, 0.0, BACKGROUND_MD, 0.0, 0.0, BACKGROUND_MD];
    }
    let mut acc = [0.0; 6];
    for d in dirs {
        for (a, b) in acc.iter_mut().zip(fibre_tensor(*d)) {
            *a += b / dirs.len() as f64;
        }
    }
    acc
}

/// The ring/cross phantom on a `dims` grid of 2 mm voxels (the shared data uses 48x48x24).
pub fn ring_cross(dims: [usize; 3]) -> Phantom {
    let (cx, cy) = ((dims[0] as f64 - 1.0) / 2.0, (dims[1] as f64 - 1.0) / 2.0);
    let scale = dims[0].min(dims[1]) as f64 / 48.0;
    let (r_in, r_out) = (10.0 * scale, 18.0 * scale);
    let (z_lo, z_hi) = ((4.0 * dims[2] as f64 / 24.0).round(), (19.0 * dims[2] as f64 / 24.0).round());
    let n = dims.iter().product();
    let mut tensors = Vec::with_capacity(n);
    let mut fibres = Vec::with_capacity(n);
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let (dx, dy) = (x as f64 - cx, y as f64 - cy);
                let r = (dx * dx + dy * dy).sqrt();
                let zf = z as f64;
                let mut dirs = Vec::new();
                if r >= r_in && r <= r_out && zf >= z_lo && zf <= z_hi {
                    dirs.push(DVec3::new(-dy, dx, 0.0).normalize());
                }
                if (dx - 14.0 * scale).abs() <= 3.0 * scale && dy.abs() <= 3.0 * scale {
                    dirs.push(DVec3::Z);
                }
                tensors.push(voxel_tensor(&dirs));
                fibres.push(dirs);
            }
        }
    }
    let world_from_voxel = DMat4::from_cols(
        DVec4::new(2.0, 0.0, 0.0, 0.0),
        DVec4::new(0.0, 2.0, 0.0, 0.0),
        DVec4::new(0.0, 0.0, 2.0, 0.0),
        DVec4::new(-(dims[0] as f64 - 1.0), -(dims[1] as f64 - 1.0), -(dims[2] as f64 - 1.0), 1.0),
    );
    Phantom { dims, world_from_voxel, tensors, fibres }
}

impl Phantom {
    /// A noiseless DWI of the phantom: `S0 = 100`, one b0 then `n_dirs` Fibonacci directions at `b`
    /// (s/mm²). Each fibre of a voxel is an equal compartment with [`FIBRE_EVALS`] (a multi-tensor signal,
    /// so crossings show two ODF lobes); the background is isotropic with [`BACKGROUND_MD`]. For ODF glyphs
    /// in scenes that need no files.
    pub fn dwi(&self, n_dirs: usize, b: f64) -> crate::Result<(Volume<f32>, crate::io::GradientTable)> {
        let dirs = crate::sh::sphere::fibonacci(n_dirs);
        let mut bvals = vec![0.0];
        let mut bvecs = vec![glam::DVec3::ZERO];
        bvals.extend(std::iter::repeat_n(b, dirs.len()));
        bvecs.extend(dirs.iter().copied());
        let gtab = crate::io::GradientTable::new(bvals, bvecs, crate::io::gradients::DEFAULT_B0_THRESHOLD)?;
        let n = self.tensors.len();
        let mut vol = Volume::zeros(&[self.dims[0], self.dims[1], self.dims[2], gtab.len()], self.world_from_voxel);
        let compartments: Vec<Vec<LowerTri>> =
            self.fibres.iter().map(|f| f.iter().map(|d| fibre_tensor(*d)).collect()).collect();
        for v in 0..n {
            for (k, (bk, g)) in gtab.bvals.iter().zip(&gtab.bvecs).enumerate() {
                let adc = |t: &LowerTri| {
                    t[0] * g.x * g.x
                        + t[2] * g.y * g.y
                        + t[5] * g.z * g.z
                        + 2.0 * (t[1] * g.x * g.y + t[3] * g.x * g.z + t[4] * g.y * g.z)
                };
                let s = if compartments[v].is_empty() {
                    (-bk * BACKGROUND_MD).exp()
                } else {
                    compartments[v].iter().map(|t| (-bk * adc(t)).exp()).sum::<f64>() / compartments[v].len() as f64
                };
                vol.data[v + n * k] = (100.0 * s) as f32;
            }
        }
        Ok((vol, gtab))
    }

    /// The FA map.
    pub fn fa(&self) -> Volume<f32> {
        let mut v = Volume::zeros(&self.dims, self.world_from_voxel);
        for (o, t) in v.data.iter_mut().zip(&self.tensors) {
            *o = crate::dti::eigh(t).map_or(0.0, |e| metrics::fa(&e.values) as f32);
        }
        v
    }
}

/// A larger phantom for benchmarks (issue #9): `dims` voxels of 1.5 mm holding four bundles (each a tube of
/// radius about 1/10 of the half field of view): a ring in the axial plane, a straight bundle along z
/// crossing the ring, a half-circle arc in the coronal plane crossing the ring from above, and a straight
/// bundle along x crossing the ring's far side; isotropic background. Crossing voxels hold two or three
/// fibres. Use [`Phantom::dwi`] for its signal and [`add_rician_noise`] for SNR.
pub fn bundles(dims: [usize; 3]) -> Phantom {
    let half = DVec3::new(dims[0] as f64 - 1.0, dims[1] as f64 - 1.0, dims[2] as f64 - 1.0) / 2.0;
    let n = dims.iter().product();
    let (mut tensors, mut fibres) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let r_tube = 0.12;
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                // Normalised coordinates in [-1, 1], z stretched to the x half-width.
                let p = (DVec3::new(x as f64, y as f64, z as f64) - half) / half;
                let mut dirs = Vec::new();
                // 1. Ring of radius 0.55 in the plane z = 0.
                let rxy = (p.x * p.x + p.y * p.y).sqrt();
                if ((rxy - 0.55).powi(2) + p.z * p.z).sqrt() <= r_tube {
                    dirs.push(DVec3::new(-p.y, p.x, 0.0).normalize());
                }
                // 2. Straight along z through the ring at (0.55, 0).
                if ((p.x - 0.55).powi(2) + p.y * p.y).sqrt() <= r_tube {
                    dirs.push(DVec3::Z);
                }
                // 3. Upper half-circle in the plane y = 0, centre (-0.3, 0, -0.2), radius 0.5.
                let q = DVec3::new(p.x + 0.3, 0.0, p.z + 0.2);
                let rq = q.length();
                if q.z >= 0.0 && ((rq - 0.5).powi(2) + p.y * p.y).sqrt() <= r_tube {
                    dirs.push(DVec3::new(-q.z, 0.0, q.x).normalize());
                }
                // 4. Straight along x through the ring's far side at y = -0.55.
                if ((p.y + 0.55).powi(2) + p.z * p.z).sqrt() <= r_tube && p.x.abs() <= 0.9 {
                    dirs.push(DVec3::X);
                }
                tensors.push(voxel_tensor(&dirs));
                fibres.push(dirs);
            }
        }
    }
    let v = 1.5;
    let world_from_voxel = DMat4::from_cols(
        DVec4::new(v, 0.0, 0.0, 0.0),
        DVec4::new(0.0, v, 0.0, 0.0),
        DVec4::new(0.0, 0.0, v, 0.0),
        DVec4::new(-half.x * v, -half.y * v, -half.z * v, 1.0),
    );
    Phantom { dims, world_from_voxel, tensors, fibres }
}

/// Rician noise for a signal with S0 = 100 at `snr` (sigma = 100 / snr): `sqrt((s + n1)² + n2²)` with n1, n2
/// normal, from a seeded generator (the same volume every run).
pub fn add_rician_noise(vol: &mut Volume<f32>, snr: f64, seed: u64) {
    let sigma = 100.0 / snr.max(1e-6);
    // splitmix64 uniforms, Box-Muller normals.
    let mut state = seed ^ 0x9e37_79b9_7f4a_7c15;
    let mut uniform = move || {
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut normal = move || {
        let (u1, u2) = (uniform().max(1e-300), uniform());
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    };
    for s in vol.data.iter_mut() {
        let (a, b) = (*s as f64 + sigma * normal(), sigma * normal());
        *s = (a * a + b * b).sqrt() as f32;
    }
}

#[cfg(test)]
mod bundle_tests {
    #[test]
    fn bundles_have_crossings_and_noise_has_the_asked_snr() {
        let ph = super::bundles([64, 64, 32]);
        let counts = ph.fibres.iter().fold([0usize; 4], |mut c, f| {
            c[f.len().min(3)] += 1;
            c
        });
        assert!(counts[1] > 2000 && counts[2] > 20, "{counts:?}");
        let (mut dwi, _) = ph.dwi(16, 1000.0).unwrap();
        let clean = dwi.data.clone();
        super::add_rician_noise(&mut dwi, 20.0, 1);
        // In the b0 volume (S = 100), the noise's standard deviation is close to 100 / 20 = 5.
        let n = ph.tensors.len();
        let d: Vec<f64> = (0..n).map(|v| (dwi.data[v] - clean[v]) as f64).collect();
        let mean = d.iter().sum::<f64>() / n as f64;
        let sd = (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64).sqrt();
        assert!((sd - 5.0).abs() < 0.2, "sd {sd}");
    }
}

/// The seed's synthetic spiral (SEEDS.md §1 figures): `n` tensors along a two-turn helix (radius 20 mm,
/// 15 mm rise per turn, axis z, centred on the origin), each with its major axis along the helix's tangent
/// and its shape sweeping the barycentric triangle: linear to planar over the first half (l2 from 0.1 to 1
/// of l1), planar to spherical over the second (l3 from 0.1 to 1). Returns (centre mm, tensor `[xx, xy,
/// yy, xz, yz, zz]` in mm²/s with l1 = 1.7e-3).
pub fn spiral(n: usize) -> Vec<(glam::DVec3, [f64; 6])> {
    use glam::{DMat3, DVec3};
    let (r, rise, turns, l1) = (20.0, 15.0, 2.0, 1.7e-3);
    (0..n)
        .map(|i| {
            let t = if n > 1 { i as f64 / (n - 1) as f64 } else { 0.0 };
            let a = t * turns * std::f64::consts::TAU;
            let h = rise / std::f64::consts::TAU;
            let centre = DVec3::new(r * a.cos(), r * a.sin(), h * a - rise * turns / 2.0);
            let tangent = DVec3::new(-r * a.sin(), r * a.cos(), h).normalize();
            let normal = DVec3::new(-a.cos(), -a.sin(), 0.0);
            let binormal = tangent.cross(normal);
            let (l2, l3) = if t < 0.5 { (0.1 + 1.8 * t, 0.1) } else { (1.0, 0.1 + 1.8 * (t - 0.5)) };
            let frame = DMat3::from_cols(tangent, normal, binormal);
            let m = frame * DMat3::from_diagonal(DVec3::new(l1, l1 * l2, l1 * l3)) * frame.transpose();
            (centre, [m.x_axis.x, m.x_axis.y, m.y_axis.y, m.x_axis.z, m.y_axis.z, m.z_axis.z])
        })
        .collect()
}

#[cfg(test)]
mod spiral_tests {
    #[test]
    fn spiral_sweeps_the_triangle_along_its_tangent() {
        use crate::dti::metrics::{WestinDenominator, westin};
        let s = super::spiral(50);
        assert_eq!(s.len(), 50);
        let shapes: Vec<[f64; 3]> =
            s.iter().map(|(_, t)| westin(&crate::dti::eigh(t).unwrap().values, WestinDenominator::Trace)).collect();
        // Starts linear, is planar half-way, ends spherical.
        assert!(shapes[0][0] > 0.7 && shapes[24][1] > 0.6 && shapes[49][2] > 0.99, "{shapes:?}");
        // Along the linear part the major axis follows the helix: within 8 degrees of the chord to the next
        // centre (half the 14.7-degree turn per step), centres about 5.3 mm apart.
        for w in s.windows(2).take(10) {
            let e1 = crate::dti::eigh(&w[0].1).unwrap().vectors[0];
            let step = w[1].0 - w[0].0;
            assert!(step.length() > 4.0 && e1.dot(step.normalize()).abs() > 8f64.to_radians().cos());
        }
    }
}
