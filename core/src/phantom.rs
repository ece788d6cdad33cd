//! A deterministic synthetic tensor field: the ring + crossing bundle of `data/phantom` (a ring around the
//! volume's z axis crossing a straight bundle along z, isotropic background), built from the tensor model
//! without noise, so the viewer and `fascicle render` need no files.

use glam::{DMat4, DVec3, DVec4};
use rayon::prelude::*;

use crate::dti::eigen::{Eigen, LowerTri, from_eigen};
use crate::dti::metrics;
use crate::volume::Volume;

/// Fibre eigenvalues (mm²/s) and the isotropic background diffusivity.
pub const FIBRE_EVALS: [f64; 3] = [1.7e-3, 0.3e-3, 0.3e-3];
/// Diffusivity of the isotropic background (mm²/s).
pub const BACKGROUND_MD: f64 = 0.8e-3;

/// The phantom's tensors and the true fibre directions per voxel (voxel axes).
pub struct Phantom {
    /// Grid size in voxels (x, y, z).
    pub dims: [usize; 3],
    /// Voxel indices to world RAS+ mm: 2 mm isotropic, axes aligned, the grid centred on the origin.
    pub world_from_voxel: DMat4,
    /// One tensor per voxel, x fastest, in mm²/s on the voxel axes: the mean of its fibres' tensors, or the
    /// isotropic background.
    pub tensors: Vec<LowerTri>,
    /// Per voxel (x fastest), the unit directions of the fibres through it: none, one or two (crossings).
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
    let mut uniform = move || (splitmix64(&mut state) >> 11) as f64 / (1u64 << 53) as f64;
    let mut normal = move || {
        let (u1, u2) = (uniform().max(1e-300), uniform());
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    };
    for s in vol.data.iter_mut() {
        let (a, b) = (*s as f64 + sigma * normal(), sigma * normal());
        *s = (a * a + b * b).sqrt() as f32;
    }
}

/// The next output of the splitmix64 generator at `state` (which it advances).
fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The ellipsoids of the 3D Shepp-Logan head phantom (Kak and Slaney's, with Toft's higher-contrast
/// intensities): intensity added inside, semi-axes, centre (all in [-1, 1]³ units), rotation about z (degrees).
const SHEPP_LOGAN: [(f64, [f64; 3], [f64; 3], f64); 10] = [
    (1.0, [0.69, 0.92, 0.81], [0.0, 0.0, 0.0], 0.0),
    (-0.8, [0.6624, 0.874, 0.78], [0.0, -0.0184, 0.0], 0.0),
    (-0.2, [0.11, 0.31, 0.22], [0.22, 0.0, 0.0], -18.0),
    (-0.2, [0.16, 0.41, 0.28], [-0.22, 0.0, 0.0], 18.0),
    (0.1, [0.21, 0.25, 0.41], [0.0, 0.35, -0.15], 0.0),
    (0.1, [0.046, 0.046, 0.05], [0.0, 0.1, 0.25], 0.0),
    (0.1, [0.046, 0.046, 0.05], [0.0, -0.1, 0.25], 0.0),
    (0.1, [0.046, 0.023, 0.05], [-0.08, -0.605, 0.0], 0.0),
    (0.1, [0.023, 0.023, 0.02], [0.0, -0.606, 0.0], 0.0),
    (0.1, [0.023, 0.046, 0.02], [0.06, -0.605, 0.0], 0.0),
];

/// The 3D Shepp-Logan phantom at `p` ([-1, 1]³): 1 in the skull, 0.2 in the brain, 0 in the ventricles, 0.3
/// in the small lesions, 0 outside.
pub fn shepp_logan_at(p: DVec3) -> f64 {
    SHEPP_LOGAN
        .iter()
        .filter(|(_, axes, centre, phi)| {
            let q = p - DVec3::from(*centre);
            let (s, c) = phi.to_radians().sin_cos();
            let r = DVec3::new(c * q.x + s * q.y, -s * q.x + c * q.y, q.z) / DVec3::from(*axes);
            r.length_squared() <= 1.0
        })
        .map(|(a, ..)| a)
        .sum()
}

/// A CT-like test volume: the 3D Shepp-Logan head on an `n`³ grid spanning 200 mm, each voxel the mean of 2³
/// point samples (partial volume at the boundaries, as a scanner's), values in [0, 1]: sharp material edges
/// and a thin bright shell, what object-order volume methods find hardest.
pub fn ct_head(n: usize) -> Volume<f32> {
    let n = n.max(2);
    let mm = 200.0 / n as f64;
    let h = (n as f64 - 1.0) / 2.0;
    let affine = DMat4::from_scale(DVec3::splat(mm)) * DMat4::from_translation(DVec3::splat(-h));
    let mut vol = Volume::zeros(&[n, n, n], affine);
    vol.data.par_chunks_mut(n * n).enumerate().for_each(|(z, plane)| {
        for (i, v) in plane.iter_mut().enumerate() {
            let (x, y) = (i % n, i / n);
            let mut acc = 0.0;
            for s in 0..8 {
                let o = DVec3::new((s & 1) as f64, ((s >> 1) & 1) as f64, ((s >> 2) & 1) as f64) * 0.5 - 0.25;
                let p = (DVec3::new(x as f64, y as f64, z as f64) + o - h) / (n as f64 / 2.0);
                acc += shepp_logan_at(p);
            }
            *v = (acc / 8.0).clamp(0.0, 1.0) as f32;
        }
    });
    vol
}

/// The scalar scene of seed 000's structure-tensor figures at `p` ([-1, 1]³): a cube, a sphere and a star of
/// six spikes (thin rods along the axes from a small ball), 1 inside and 0 outside.
pub fn cube_sphere_spikes_at(p: DVec3) -> f64 {
    let cube = (p - DVec3::new(-0.45, -0.45, 0.0)).abs().max_element() <= 0.28;
    let sphere = (p - DVec3::new(0.45, 0.4, 0.0)).length() <= 0.32;
    let q = p - DVec3::new(-0.4, 0.45, 0.0);
    let spikes = q.length() <= 0.1
        || (0..3).any(|k| {
            let mut off = q;
            off[k] = 0.0;
            q[k].abs() <= 0.4 && off.length() <= 0.035
        });
    f64::from(u8::from(cube || sphere || spikes))
}

/// Seed 000's 64³ structure-tensor field (Kindlmann's test scene): the scalar scene
/// ([`cube_sphere_spikes_at`], each voxel the mean of 2³ samples) on an `n`³ grid of unit voxels, its
/// gradient g by central differences, and at each voxel the structure tensor `J = w * (g gᵀ)` smoothed with the
/// binomial kernel [1, 2, 1] / 4 along each axis. Returned for the voxels where `tr J` is at least 1 % of its
/// largest value (elsewhere the field is flat): (voxel centre, centred on the origin; tensor as
/// lower-triangular `[xx, xy, yy, xz, yz, zz]`, scaled so the largest eigenvalue in the field is 1e-3, the
/// size of a diffusion tensor in mm²/s).
pub fn structure_tensor_field(n: usize) -> Vec<(DVec3, [f64; 6])> {
    let n = n.max(4);
    let h = (n as f64 - 1.0) / 2.0;
    let idx = |x: usize, y: usize, z: usize| x + n * (y + n * z);
    let f: Vec<f64> = (0..n * n * n)
        .into_par_iter()
        .map(|i| {
            let c = DVec3::new((i % n) as f64, ((i / n) % n) as f64, (i / (n * n)) as f64);
            (0..8)
                .map(|s| {
                    let o = DVec3::new((s & 1) as f64, ((s >> 1) & 1) as f64, ((s >> 2) & 1) as f64) * 0.5 - 0.25;
                    cube_sphere_spikes_at((c + o - h) / (n as f64 / 2.0))
                })
                .sum::<f64>()
                / 8.0
        })
        .collect();
    let at = |x: isize, y: isize, z: isize| {
        let c = |v: isize| v.clamp(0, n as isize - 1) as usize;
        f[idx(c(x), c(y), c(z))]
    };
    let mut j: Vec<[f64; 6]> = (0..n * n * n)
        .into_par_iter()
        .map(|i| {
            let (x, y, z) = ((i % n) as isize, ((i / n) % n) as isize, (i / (n * n)) as isize);
            let g = DVec3::new(
                at(x + 1, y, z) - at(x - 1, y, z),
                at(x, y + 1, z) - at(x, y - 1, z),
                at(x, y, z + 1) - at(x, y, z - 1),
            ) / 2.0;
            [g.x * g.x, g.x * g.y, g.y * g.y, g.x * g.z, g.y * g.z, g.z * g.z]
        })
        .collect();
    // Separable binomial smoothing, one axis at a time.
    for axis in 0..3 {
        let stride = [1, n, n * n][axis];
        let prev = j.clone();
        j.par_iter_mut().enumerate().for_each(|(i, t)| {
            let c = [i % n, (i / n) % n, i / (n * n)][axis];
            let lo = if c > 0 { i - stride } else { i };
            let hi = if c + 1 < n { i + stride } else { i };
            for k in 0..6 {
                t[k] = 0.25 * prev[lo][k] + 0.5 * prev[i][k] + 0.25 * prev[hi][k];
            }
        });
    }
    let trace = |t: &[f64; 6]| t[0] + t[2] + t[5];
    let max_trace = j.iter().map(trace).fold(0.0, f64::max);
    if max_trace <= 0.0 {
        return Vec::new();
    }
    let largest = j
        .iter()
        .filter(|t| trace(t) >= 0.01 * max_trace)
        .filter_map(|t| crate::dti::eigen::eigh(t).map(|e| e.values[0]))
        .fold(0.0, f64::max);
    let scale = 1e-3 / largest.max(f64::MIN_POSITIVE);
    j.iter()
        .enumerate()
        .filter(|(_, t)| trace(t) >= 0.01 * max_trace)
        .map(|(i, t)| {
            let c = DVec3::new((i % n) as f64, ((i / n) % n) as f64, (i / (n * n)) as f64) - h;
            (c, t.map(|v| v * scale))
        })
        .collect()
}

#[cfg(test)]
mod ct_tests {
    use glam::DVec3;

    #[test]
    fn structure_tensors_are_planar_on_faces_and_linear_along_spikes() {
        use crate::dti::metrics::{WestinDenominator, westin};
        let field = super::structure_tensor_field(64);
        assert!(field.len() > 5_000 && field.len() < 64 * 64 * 64 / 2, "{} tensors", field.len());
        let near = |p: DVec3| {
            field.iter().min_by(|a, b| (a.0 - p).length().total_cmp(&(b.0 - p).length())).map(|(c, t)| (*c, *t))
        };
        // Units: [-1, 1]³ maps to voxel centres -31.5..31.5 (32 voxels per unit).
        let vox = |p: DVec3| p * 32.0;
        // On the cube's +x face (x = -0.45 + 0.28), away from its edges: the gradient is along x, so the
        // tensor is a stick (one large eigenvalue, e1 along x): linear in Westin's terms, a disc as a splat.
        let (_, t) = near(vox(DVec3::new(-0.17, -0.45, 0.0))).unwrap();
        let e = crate::dti::eigen::eigh(&t).unwrap();
        let [cl, _, _] = westin(&e.values, WestinDenominator::Trace);
        assert!(cl > 0.8 && e.vectors[0].x.abs() > 0.95, "cube face: cl {cl}, e1 {}", e.vectors[0]);
        // Along a spike (the rod along x from the ball at (-0.4, 0.45, 0)), gradients point around the rod's
        // axis: two equal large eigenvalues across it (planar), the smallest along the rod.
        let (_, t) = near(vox(DVec3::new(-0.15, 0.45, 0.035))).unwrap();
        let e = crate::dti::eigen::eigh(&t).unwrap();
        let [_, cp, _] = westin(&e.values, WestinDenominator::Trace);
        assert!(cp > 0.3 && e.vectors[2].x.abs() > 0.9, "spike: cp {cp}, e3 {}", e.vectors[2]);
        // Scaled: the largest eigenvalue is 1e-3.
        let top = field.iter().filter_map(|(_, t)| crate::dti::eigen::eigh(t)).map(|e| e.values[0]).fold(0.0, f64::max);
        assert!((top - 1e-3).abs() < 1e-12, "{top}");
    }

    #[test]
    fn ct_head_has_the_shepp_logan_materials() {
        let n = 64;
        let v = super::ct_head(n);
        let at = |x: usize, y: usize, z: usize| v.data[x + n * (y + n * z)];
        // Centre: brain (1 - 0.8); a point in the left ventricle (ellipsoid 4 at x = -0.22): 0; the skull on
        // the x axis (between the semi-axes 0.6624 and 0.69 of the two outer ellipsoids): 1; outside: 0.
        let vox = |p: f64| ((p * n as f64 / 2.0) + (n as f64 - 1.0) / 2.0).round() as usize;
        assert!((at(vox(0.0), vox(0.0), vox(0.0)) - 0.2).abs() < 1e-6);
        assert!(at(vox(-0.22), vox(0.0), vox(0.0)).abs() < 1e-6);
        assert_eq!(super::shepp_logan_at(DVec3::new(0.675, 0.0, 0.0)), 1.0);
        assert_eq!(at(0, 0, 0), 0.0);
        // Partial volume: some voxels between the materials' values.
        let mixed = v.data.iter().filter(|x| **x > 0.02 && (**x - 0.2).abs() > 0.02 && **x < 0.98).count();
        assert!(mixed > 1000 && v.data.iter().all(|x| (0.0..=1.0).contains(x)), "{mixed} mixed voxels");
        // 200 mm across.
        let p = v.world_from_voxel.transform_point3(DVec3::splat(n as f64 - 0.5));
        assert!((p.x - 100.0).abs() < 1e-9, "{p}");
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

/// Half-axes of the brain-sized ellipsoid that [`whole_brain_streamlines`] fills (mm, x y z, centred at 0).
pub const BRAIN_HALF_AXES: [f32; 3] = [65.0, 80.0, 55.0];

/// Streamlines `first..first + n` of a deterministic whole-brain-sized tractogram: smooth random curves at
/// 1 mm steps, 40 to 160 points each (mean 100, as `tckgen` makes them at whole-brain scale), inside an
/// ellipsoid of a brain's size ([`BRAIN_HALF_AXES`]), reflected at its surface. Each streamline depends only on
/// `seed` and its index, so any range can be made on its own, in parallel, in bounded memory: a file of
/// 1M or 10M streamlines is written chunk by chunk.
pub fn whole_brain_streamlines(seed: u64, first: usize, n: usize) -> crate::io::Tractogram {
    use glam::Vec3;
    let half = Vec3::from(BRAIN_HALF_AXES);
    let lines: Vec<Vec<Vec3>> = (first..first + n)
        .into_par_iter()
        .map(|i| {
            let mut state = seed ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0xD1B5_4A32_D192_ED03;
            let mut next = move || (splitmix64(&mut state) >> 40) as f32 / (1u64 << 24) as f32;
            let unit = |next: &mut dyn FnMut() -> f32| loop {
                let v = Vec3::new(next(), next(), next()) * 2.0 - 1.0;
                let l = v.length_squared();
                if l > 1e-4 && l <= 1.0 {
                    break v / l.sqrt();
                }
            };
            let len = 40 + (next() * 121.0) as usize;
            let r = next().cbrt() * 0.95;
            let mut p = unit(&mut next) * r * half;
            let mut d = unit(&mut next);
            let mut pts = Vec::with_capacity(len.min(160));
            for _ in 0..len.min(160) {
                pts.push(p);
                d = (d + unit(&mut next) * 0.08).normalize();
                let q = p + d;
                let s = q / half;
                if s.length_squared() > 1.0 {
                    // Reflect off the ellipsoid: its normal there is the gradient of |x / half|².
                    let normal = (s / half).normalize();
                    d = (d - 2.0 * d.dot(normal) * normal).normalize();
                }
                p += d;
            }
            pts
        })
        .collect();
    let mut t = crate::io::Tractogram::new();
    t.points.reserve(lines.iter().map(Vec::len).sum());
    for l in &lines {
        t.push(l);
    }
    t
}

/// Writes [`whole_brain_streamlines`]`(seed, 0, n)` to `path` (`.tck`, `.trk`, `.trx`, by the name), 20,000
/// streamlines at a time; a `.trk` in a 1 mm grid over the ellipsoid. The streamlines written.
pub fn write_whole_brain(path: &std::path::Path, n: usize, seed: u64) -> crate::Result<usize> {
    use crate::io::stream::{TractogramWriter, WriteOptions};
    let half = DVec3::new(BRAIN_HALF_AXES[0] as f64, BRAIN_HALF_AXES[1] as f64, BRAIN_HALF_AXES[2] as f64);
    let dims = (half * 2.0 + 1.0).to_array().map(|v| v as usize);
    let options = WriteOptions { trk_space: Some((DMat4::from_translation(-half), dims)), ..Default::default() };
    let mut w = TractogramWriter::create(path, &options)?;
    const BLOCK: usize = 20_000;
    for first in (0..n).step_by(BLOCK) {
        w.write_chunk(&whole_brain_streamlines(seed, first, BLOCK.min(n - first)))?;
    }
    w.finish()
}
