//! Direction fields: what the tracker follows. The tracker knows nothing of the model behind a field (DIPY's
//! separation of direction getter and tracker): a field answers "which way, how anisotropic, which tensor" at
//! a point in voxel coordinates.
//!
//! Two interpolations of a gridded tensor field, both trilinear on `[-0.5, dim - 0.5)` with edge voxels
//! replicated outside their centres (as DIPY):
//! - [`TensorInterpolation::Componentwise`] (default, what DIPY and most trackers do): the six components
//!   are blended linearly. Cheap, but a blend of two differently oriented tensors "swells": its determinant
//!   exceeds that of both inputs, so FA dips between voxels of crossing orientation.
//! - [`TensorInterpolation::LogEuclidean`] (Arsigny 2006): the matrix logarithms are blended and the result
//!   exponentiated. Determinants interpolate geometrically (no swelling) and positive-definiteness is kept.
//!   The principal direction of `exp(L)` is that of `L`, so tracking needs no exponential per stage; the
//!   exponential is taken only for the tensors recorded at output points.
//!
//! The stopping scalar is the FA map interpolated trilinearly (DIPY's `ThresholdStoppingCriterion`), not
//! the FA of the interpolated tensor.

use glam::DVec3;
use rayon::prelude::*;

use crate::dti::eigen::{Eigen, LowerTri, eigh, from_eigen};
use crate::dti::{TensorVolume, metrics};
use crate::error::{Error, Result};
use crate::volume::Volume;

/// What a field returns at a point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FieldSample {
    /// Unit direction in the voxel-aligned millimetre frame (the gradient frame); its sign is arbitrary.
    pub direction: DVec3,
    /// The stopping scalar (FA for tensor fields).
    pub fa: f64,
}

/// A field the tracker can follow.
pub trait DirectionField: Sync {
    /// Spatial grid size; points are valid on `[-0.5, dim - 0.5)` per axis.
    fn dims(&self) -> [usize; 3];
    /// Voxel edge lengths in mm (a step of `h` mm along `d` moves `h d / voxel_size` voxels).
    fn voxel_size(&self) -> DVec3;
    /// Direction and stopping scalar at voxel coordinate `p` (inside the grid); `None` where there is no
    /// usable direction (no data, a zero or non-finite tensor). `reference` is the direction the track
    /// arrives along (unit, or zero where there is none yet): fields with several directions per voxel
    /// follow the one closest to it, and the returned direction may have either sign.
    fn sample(&self, p: DVec3, reference: DVec3) -> Option<FieldSample>;
    /// The directions to start tracks along from a seed at `p`, each with the stopping scalar there
    /// (one streamline per entry, traced both ways). Default: the field's one direction.
    fn seed_samples(&self, p: DVec3, out: &mut Vec<FieldSample>) {
        out.clear();
        out.extend(self.sample(p, DVec3::ZERO));
    }
    /// The tensor at `p` in the voxel-aligned frame, recorded at output points.
    fn tensor(&self, p: DVec3) -> LowerTri;
}

/// Whether a voxel coordinate lies in the grid, `[-0.5, dim - 0.5)` on each axis.
#[inline]
pub fn in_grid(dims: [usize; 3], p: DVec3) -> bool {
    (0..3).all(|i| p[i] >= -0.5 && p[i] < dims[i] as f64 - 0.5)
}

/// How tensors are blended between voxel centres.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum TensorInterpolation {
    /// The six components blended linearly (the default; DIPY's choice). FA dips between crossing orientations.
    #[default]
    Componentwise,
    /// The matrix logarithms blended (Arsigny 2006): no swelling, positive-definiteness kept.
    LogEuclidean,
}

impl std::str::FromStr for TensorInterpolation {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_lowercase().replace(['-', '_'], "").as_str() {
            "componentwise" | "linear" => Ok(Self::Componentwise),
            "logeuclidean" | "log" => Ok(Self::LogEuclidean),
            _ => Err(Error::Param(format!("unknown tensor interpolation '{s}' (use componentwise or log-euclidean)"))),
        }
    }
}

/// A gridded tensor field: per voxel the tensor (or its logarithm) and FA, packed for trilinear blending.
/// Voxels without a usable tensor (outside the fit mask, failed fits, non-finite input) hold zeros, so FA
/// falls to 0 towards them and tracks stop there.
#[derive(Clone, Debug)]
pub struct TensorField {
    dims: [usize; 3],
    voxel_size: DVec3,
    interpolation: TensorInterpolation,
    /// Tensor (or log-tensor) components then FA.
    cells: Vec<[f64; 7]>,
}

/// Eigenvalues below this fraction of the largest are raised to it before taking logarithms.
const LOG_FLOOR: f64 = 1e-6;

impl TensorField {
    /// From per-voxel tensors in DIPY's lower-triangular order (`None` = no data).
    pub fn new(
        dims: [usize; 3],
        voxel_size: DVec3,
        tensors: impl IntoIterator<Item = Option<LowerTri>>,
        interpolation: TensorInterpolation,
    ) -> Result<Self> {
        check_grid(dims, voxel_size)?;
        let cells: Vec<[f64; 7]> = tensors.into_iter().map(|t| cell(t, interpolation)).collect();
        let n: usize = dims.iter().product();
        if cells.len() != n {
            return Err(Error::Shape(format!("{} tensors for a {dims:?} grid ({n} voxels)", cells.len())));
        }
        Ok(Self { dims, voxel_size, interpolation, cells })
    }

    /// From a fit: the clipped tensors DIPY stores (`TensorFit::tensor`).
    pub fn from_fit(fit: &TensorVolume, voxel_size: DVec3, interpolation: TensorInterpolation) -> Result<Self> {
        Self::new(fit.dims, voxel_size, (0..fit.voxels.len()).map(|v| fit.fit_at(v).map(|t| t.tensor())), interpolation)
    }

    /// From a tensor image as `fascicle fit dti` and DIPY write it: (X,Y,Z,6) or (X,Y,Z,1,6), lower-triangular.
    pub fn from_volume(vol: &Volume<f64>, interpolation: TensorInterpolation) -> Result<Self> {
        check_tensor_image(vol)?;
        let n = vol.n_voxels();
        let tensors = (0..n).map(|v| Some(std::array::from_fn(|c| vol.data[v + n * c])));
        Self::new(vol.dims3(), vol.voxel_size(), tensors, interpolation)
    }

    /// FA at voxel centre `v` (flat NIfTI index); 0 where there is no tensor.
    pub fn fa_at(&self, v: usize) -> f64 {
        self.cells[v][6]
    }

    /// Trilinear blend of the 7 packed values at `p` (which must be in the grid; edge voxels are
    /// replicated outside their centres).
    #[inline]
    fn blend(&self, p: DVec3) -> [f64; 7] {
        let mut out = [0.0; 7];
        for (i, w) in trilinear(self.dims, p) {
            let v = &self.cells[i];
            for k in 0..7 {
                out[k] += w * v[k];
            }
        }
        out
    }
}

/// The 8 voxels (flat NIfTI indices) around `p` and their trilinear weights. `p` must be in the grid
/// (`[-0.5, dim - 0.5)`); outside the outermost centres the edge voxels are replicated (as DIPY).
#[inline]
pub fn trilinear(dims: [usize; 3], p: DVec3) -> [(usize, f64); 8] {
    let [nx, ny, _] = dims;
    let (x0, sx, wx) = axis(p.x, dims[0]);
    let (y0, sy, wy) = axis(p.y, dims[1]);
    let (z0, sz, wz) = axis(p.z, dims[2]);
    let base = x0 + nx * (y0 + ny * z0);
    let (sy, sz) = (sy * nx, sz * nx * ny);
    [
        (base, (1.0 - wx) * (1.0 - wy) * (1.0 - wz)),
        (base + sx, wx * (1.0 - wy) * (1.0 - wz)),
        (base + sy, (1.0 - wx) * wy * (1.0 - wz)),
        (base + sx + sy, wx * wy * (1.0 - wz)),
        (base + sz, (1.0 - wx) * (1.0 - wy) * wz),
        (base + sx + sz, wx * (1.0 - wy) * wz),
        (base + sy + sz, (1.0 - wx) * wy * wz),
        (base + sx + sy + sz, wx * wy * wz),
    ]
}

/// Along one axis: the lower voxel index, the stride to the upper one (0 where the upper would leave the
/// grid) and the upper weight. `c + 1 >= 0.5`, so truncation is the floor (no libm call where the target lacks
/// SSE4.1's round).
#[inline]
fn axis(c: f64, n: usize) -> (usize, usize, f64) {
    let t = (c + 1.0) as usize;
    let w = c + 1.0 - t as f64;
    if t == 0 {
        (0, 0, w)
    } else {
        let i = t - 1;
        if i + 1 < n { (i, 1, w) } else { (n - 1, 0, w) }
    }
}

/// [`trilinear`] with f32 weights, for fields stored in f32.
#[inline]
fn trilinear_f32(dims: [usize; 3], p: DVec3) -> ([usize; 8], [f32; 8]) {
    let [nx, ny, _] = dims;
    let axis = |c: f64, n: usize| {
        let (i, s, w) = axis(c, n);
        (i, s, w as f32)
    };
    let (x0, sx, wx) = axis(p.x, dims[0]);
    let (y0, sy, wy) = axis(p.y, dims[1]);
    let (z0, sz, wz) = axis(p.z, dims[2]);
    let base = x0 + nx * (y0 + ny * z0);
    let (sy, sz) = (sy * nx, sz * nx * ny);
    let (ux, uy, uz) = (1.0 - wx, 1.0 - wy, 1.0 - wz);
    let (a, b, c, d) = (uy * uz, wy * uz, uy * wz, wy * wz);
    (
        [base, base + sx, base + sy, base + sx + sy, base + sz, base + sx + sz, base + sy + sz, base + sx + sy + sz],
        [ux * a, wx * a, ux * b, wx * b, ux * c, wx * c, ux * d, wx * d],
    )
}

fn cell(t: Option<LowerTri>, interpolation: TensorInterpolation) -> [f64; 7] {
    let Some(t) = t.filter(|t| t.iter().all(|v| v.is_finite())) else { return [0.0; 7] };
    let Some(e) = eigh(&t) else { return [0.0; 7] };
    let fa = metrics::fa(&e.values);
    let packed = match interpolation {
        TensorInterpolation::Componentwise => t,
        TensorInterpolation::LogEuclidean => {
            let top = e.values[0];
            if top <= 0.0 {
                return [0.0; 7];
            }
            let values = e.values.map(|l| l.max(top * LOG_FLOOR).ln());
            from_eigen(&Eigen { values, vectors: e.vectors })
        }
    };
    let fa = if fa.is_finite() { fa } else { 0.0 };
    [packed[0], packed[1], packed[2], packed[3], packed[4], packed[5], fa]
}

impl DirectionField for TensorField {
    fn dims(&self) -> [usize; 3] {
        self.dims
    }
    fn voxel_size(&self) -> DVec3 {
        self.voxel_size
    }
    #[inline]
    fn sample(&self, p: DVec3, _reference: DVec3) -> Option<FieldSample> {
        let c = self.blend(p);
        let t = [c[0], c[1], c[2], c[3], c[4], c[5]];
        principal_direction(&t).map(|direction| FieldSample { direction, fa: c[6] })
    }
    fn tensor(&self, p: DVec3) -> LowerTri {
        let c = self.blend(p);
        let t = [c[0], c[1], c[2], c[3], c[4], c[5]];
        match self.interpolation {
            TensorInterpolation::Componentwise => t,
            TensorInterpolation::LogEuclidean => match eigh(&t) {
                Some(e) => from_eigen(&Eigen { values: e.values.map(f64::exp), vectors: e.vectors }),
                None => [0.0; 6],
            },
        }
    }
}

/// The unit eigenvector of the largest eigenvalue of a symmetric tensor, sign arbitrary; `None` for a zero
/// or non-finite tensor.
///
/// Fast path: the largest eigenvalue by Newton on the characteristic cubic (no trigonometry; the tensor
/// scaled to unit largest entry), the eigenvector as the largest cross product of two
/// rows of `T - l1 I` (which spans its null space), then once more with the Rayleigh quotient as `l1`. The
/// error is then `~eps |T| / (l1 - l2)`, as Jacobi's (tested on 200,000 tensors). When the two largest
/// eigenvalues are within 1e-4 |T| (an oblate tensor, where the direction is ill-defined anyway) the Jacobi
/// solver is used instead.
#[inline]
pub fn principal_direction(t: &LowerTri) -> Option<DVec3> {
    let scale = t.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if !(scale.is_finite() && scale > 0.0) {
        return None;
    }
    let a = t.map(|v| v / scale);
    let (xx, xy, yy, xz, yz, zz) = (a[0], a[1], a[2], a[3], a[4], a[5]);
    let q = (xx + yy + zz) / 3.0;
    let (dx, dy, dz) = (xx - q, yy - q, zz - q);
    let p2 = dx * dx + dy * dy + dz * dz + 2.0 * (xy * xy + xz * xz + yz * yz);
    if p2 < 1e-24 {
        return None; // isotropic: no direction
    }
    // Largest eigenvalue x of the traceless B = A - qI: the largest root of x³ - (p2/2) x - det B, by
    // Newton from the upper bound sqrt(2 p2 / 3). The cubic is convex there, so the iterates fall
    // monotonically onto the root (quadratically once near; exact at once for a prolate tensor).
    let det = dx * (dy * dz - yz * yz) - xy * (xy * dz - yz * xz) + xz * (xy * yz - dy * xz);
    let half_p2 = 0.5 * p2;
    let mut x = (p2 * (2.0 / 3.0)).sqrt();
    for _ in 0..64 {
        let f = x * (x * x - half_p2) - det;
        let df = 3.0 * x * x - half_p2;
        if !(f > 0.0 && df > 0.0) {
            break;
        }
        let step = f / df;
        x -= step;
        if step <= 1e-9 * x.abs() {
            break;
        }
    }
    // The other two roots of the deflated quadratic x'² + x x' + (x² - p2/2).
    let x2 = 0.5 * (-x + (2.0 * p2 - 3.0 * x * x).max(0.0).sqrt());
    let l1 = q + x;
    // `a` is scaled to unit largest entry, so this gap is relative to |T| (rounding errors are relative to
    // |T|, not to the deviatoric size).
    if x - x2 < 1e-4 {
        return eigh(t).map(|e| e.vectors[0]);
    }
    let null_vector = |l: f64| -> Option<DVec3> {
        let r0 = DVec3::new(xx - l, xy, xz);
        let r1 = DVec3::new(xy, yy - l, yz);
        let r2 = DVec3::new(xz, yz, zz - l);
        let c = [r0.cross(r1), r0.cross(r2), r1.cross(r2)];
        let best = c.into_iter().max_by(|u, v| u.length_squared().total_cmp(&v.length_squared()))?;
        let n2 = best.length_squared();
        (n2 > 0.0 && n2.is_finite()).then(|| best / n2.sqrt())
    };
    let Some(v) = null_vector(l1) else { return eigh(t).map(|e| e.vectors[0]) };
    // One refinement: the Rayleigh quotient is accurate to the square of the vector's error, which takes
    // the closed form's rounding out of the eigenvalue.
    let av = DVec3::new(xx * v.x + xy * v.y + xz * v.z, xy * v.x + yy * v.y + yz * v.z, xz * v.x + yz * v.y + zz * v.z);
    null_vector(v.dot(av)).or(Some(v))
}

/// Up to `npeaks` directions per voxel and a stopping scalar, interpolated as DIPY's EuDX does: at each of
/// the 8 voxels around a point, the peak closest to the incoming direction (by |cos|), flipped to agree with
/// it, weighted trilinearly; the sum normalised. The stopping scalar (FA, GFA) is blended trilinearly.
///
/// With one peak per voxel from a tensor fit (the principal eigenvector, [`PeakField::from_tensors`]) this
/// is the fast tensor tracker: the eigen-decompositions happen once per voxel, not at every integration
/// stage, and a sample is 8 loads of 16 bytes and 8 dot products. Unlike blending the tensors, it does
/// not let a neighbour's minor axes pull the direction, and at a crossing it keeps following the
/// peak nearest the incoming direction.
#[derive(Clone, Debug)]
pub struct PeakField {
    dims: [usize; 3],
    voxel_size: DVec3,
    npeaks: usize,
    /// `npeaks` slots per voxel: a unit direction (zero where the voxel has fewer peaks) and, in slot 0's
    /// fourth lane, the stopping scalar.
    cells: Vec<[f32; 4]>,
    /// Per voxel the tensor (lower-triangular), when the peaks come from tensors: recorded at output points.
    tensors: Option<Vec<[f32; 6]>>,
    /// A voxel whose closest peak is farther than this from the incoming direction (`|cos|` below it) is
    /// left out of the blend (DIPY's EuDX angle gate; default cos 60°).
    cos_gate: f32,
}

/// The blend fails (no direction) when the voxels left in it weigh less than this (DIPY's EuDX).
const MIN_TOTAL_WEIGHT: f32 = 0.5;
const DEFAULT_GATE_DEG: f64 = 60.0;

impl PeakField {
    /// From per-voxel peaks (`npeaks` per voxel, voxel-major; zero vectors pad voxels with fewer) in the
    /// voxel-aligned mm frame, and a stopping scalar per voxel. Non-finite values become "no peak" / 0.
    pub fn new(dims: [usize; 3], voxel_size: DVec3, npeaks: usize, peaks: &[[f32; 3]], scalar: &[f32]) -> Result<Self> {
        let n: usize = dims.iter().product();
        check_grid(dims, voxel_size)?;
        if npeaks == 0 || peaks.len() != n * npeaks || scalar.len() != n {
            return Err(Error::Shape(format!(
                "a peak field on {dims:?} needs {npeaks} > 0 peaks and one scalar per voxel ({} peaks, {} scalars \
                 given for {n} voxels)",
                peaks.len(),
                scalar.len()
            )));
        }
        let mut cells = vec![[0.0f32; 4]; n * npeaks];
        for (c, p) in cells.iter_mut().zip(peaks) {
            let v = glam::Vec3::from_array(*p);
            let len = v.length();
            if len.is_finite() && len > 0.0 {
                let u = v / len;
                *c = [u.x, u.y, u.z, 0.0];
            }
        }
        for (v, s) in scalar.iter().enumerate() {
            cells[v * npeaks][3] = if s.is_finite() { *s } else { 0.0 };
        }
        Ok(Self { dims, voxel_size, npeaks, cells, tensors: None, cos_gate: gate(DEFAULT_GATE_DEG) })
    }

    /// One peak per voxel, the principal eigenvector, with FA as the stopping scalar, from tensors in
    /// DIPY's lower-triangular order (`None` = no data). The tensors are kept for [`DirectionField::tensor`].
    pub fn from_tensors(
        dims: [usize; 3],
        voxel_size: DVec3,
        tensors: impl IntoIterator<Item = Option<LowerTri>>,
    ) -> Result<Self> {
        check_grid(dims, voxel_size)?;
        let tensors: Vec<[f32; 6]> = tensors
            .into_iter()
            .map(|t| match t.filter(|t| t.iter().all(|v| v.is_finite())) {
                Some(t) => t.map(|v| v as f32),
                None => [0.0; 6],
            })
            .collect();
        let n: usize = dims.iter().product();
        if tensors.len() != n {
            return Err(Error::Shape(format!("{} tensors for a {dims:?} grid ({n} voxels)", tensors.len())));
        }
        let cells =
            tensors.par_iter().map(|t| eigh(&t.map(f64::from)).map_or([0.0; 4], |e| principal_cell(&e))).collect();
        Ok(Self::of_tensors(dims, voxel_size, cells, tensors))
    }

    /// From a fit: the principal eigenvector and FA of each fitted voxel (the eigen-systems the fit has
    /// already computed), and the clipped tensors DIPY stores.
    pub fn from_fit(fit: &TensorVolume, voxel_size: DVec3) -> Result<Self> {
        check_grid(fit.dims, voxel_size)?;
        let n = fit.voxels.len();
        let (cells, tensors): (Vec<[f32; 4]>, Vec<[f32; 6]>) = (0..n)
            .into_par_iter()
            .map(|v| match fit.fit_at(v).map(|f| (principal_cell(&f.eigen), f)) {
                Some((cell, f)) if cell != [0.0; 4] => (cell, f.tensor().map(|x| x as f32)),
                _ => ([0.0; 4], [0.0; 6]),
            })
            .unzip();
        Ok(Self::of_tensors(fit.dims, voxel_size, cells, tensors))
    }

    /// One peak per voxel (`cells` from [`principal_cell`]) with the tensors kept, gated at the default angle.
    fn of_tensors(dims: [usize; 3], voxel_size: DVec3, cells: Vec<[f32; 4]>, tensors: Vec<[f32; 6]>) -> Self {
        Self { dims, voxel_size, npeaks: 1, cells, tensors: Some(tensors), cos_gate: gate(DEFAULT_GATE_DEG) }
    }

    /// From a tensor image as `fascicle fit dti` and DIPY write it: (X,Y,Z,6) or (X,Y,Z,1,6), lower-triangular.
    pub fn from_tensor_volume(vol: &Volume<f64>) -> Result<Self> {
        check_tensor_image(vol)?;
        let n = vol.n_voxels();
        let tensors = (0..n).map(|v| Some(std::array::from_fn(|c| vol.data[v + n * c])));
        Self::from_tensors(vol.dims3(), vol.voxel_size(), tensors)
    }

    /// From extracted ODF peaks ([`crate::sh::peaks_from_sh`]) with a stopping scalar per voxel (GFA, FA, ...).
    /// Peaks whose ODF value is at or below `value_threshold` are left out (DIPY's EuDX: 0.0239).
    pub fn from_peaks(
        peaks: &crate::sh::PeakVolume,
        voxel_size: DVec3,
        scalar: &[f32],
        value_threshold: f32,
    ) -> Result<Self> {
        let dirs: Vec<[f32; 3]> = peaks
            .dirs
            .iter()
            .zip(&peaks.values)
            .map(|(d, &v)| if v > value_threshold { *d } else { [0.0; 3] })
            .collect();
        Self::new(peaks.dims, voxel_size, peaks.npeaks, &dirs, scalar)
    }

    /// Leave out of the blend any voxel whose closest peak turns more than `deg` from the incoming direction
    /// (default 60°, DIPY's EuDX; set it to the tracker's maximum angle).
    pub fn with_max_angle(mut self, deg: f64) -> Self {
        self.cos_gate = gate(deg);
        self
    }

    /// Peak slots per voxel (1 for a field made from tensors).
    pub fn npeaks(&self) -> usize {
        self.npeaks
    }

    /// The stopping scalar at voxel centre `v` (flat NIfTI index).
    pub fn scalar_at(&self, v: usize) -> f64 {
        f64::from(self.cells[v * self.npeaks][3])
    }

    /// The peaks of voxel `v` (zero vectors where it has fewer).
    pub fn peaks_at(&self, v: usize) -> impl Iterator<Item = DVec3> + '_ {
        self.cells[v * self.npeaks..(v + 1) * self.npeaks].iter().map(|c| glam::Vec3::new(c[0], c[1], c[2]).as_dvec3())
    }

    fn nearest_voxel(&self, p: DVec3) -> usize {
        let [nx, ny, nz] = self.dims;
        let r = p.round();
        let (x, y, z) =
            (r.x.clamp(0.0, nx as f64 - 1.0), r.y.clamp(0.0, ny as f64 - 1.0), r.z.clamp(0.0, nz as f64 - 1.0));
        x as usize + nx * (y as usize + ny * z as usize)
    }
}

/// A tensor's cell: its principal eigenvector and FA, or zeros where it has no positive, finite eigenvalues.
fn principal_cell(e: &Eigen) -> [f32; 4] {
    if !(e.values[0] > 0.0 && e.values.iter().all(|l| l.is_finite())) {
        return [0.0; 4];
    }
    let fa = metrics::fa(&e.values);
    let d = e.vectors[0];
    [d.x as f32, d.y as f32, d.z as f32, if fa.is_finite() { fa as f32 } else { 0.0 }]
}

fn gate(deg: f64) -> f32 {
    // A hair below the cosine, so that a peak exactly at the angle stays in (f32 rounding).
    (deg.clamp(0.0, 90.0).to_radians().cos() - 1e-6).max(0.0) as f32
}

fn check_grid(dims: [usize; 3], voxel_size: DVec3) -> Result<()> {
    if dims.contains(&0) {
        return Err(Error::Shape(format!("a direction field needs a non-empty grid, not {dims:?}")));
    }
    if !voxel_size.is_finite() || voxel_size.min_element() <= 0.0 {
        return Err(Error::Param(format!("voxel size {voxel_size} must be finite and positive")));
    }
    Ok(())
}

fn check_tensor_image(vol: &Volume<f64>) -> Result<()> {
    if vol.shape.len() < 4 || vol.n_channels() != 6 || vol.shape[3..].iter().filter(|&&d| d != 1).count() > 1 {
        return Err(Error::Shape(format!(
            "a tensor image must be (X,Y,Z,6) or (X,Y,Z,1,6) in lower-triangular order; this one is {:?}",
            vol.shape
        )));
    }
    Ok(())
}

impl DirectionField for PeakField {
    fn dims(&self) -> [usize; 3] {
        self.dims
    }
    fn voxel_size(&self) -> DVec3 {
        self.voxel_size
    }
    #[inline]
    fn sample(&self, p: DVec3, reference: DVec3) -> Option<FieldSample> {
        let k = self.npeaks;
        let mut r = reference.as_vec3();
        if r == glam::Vec3::ZERO {
            // No incoming direction yet: the nearest voxel's largest peak.
            let c = self.cells[self.nearest_voxel(p) * k];
            r = glam::Vec3::new(c[0], c[1], c[2]);
        }
        let gate = self.cos_gate;
        let (mut acc, mut s, mut total) = (glam::Vec3::ZERO, 0.0f32, 0.0f32);
        if k == 1 {
            // The tensor case: one peak per voxel, no choice to make; weights in f32, no branches.
            let (idx, w) = trilinear_f32(self.dims, p);
            for (i, w) in idx.into_iter().zip(w) {
                let c = self.cells[i];
                let v = glam::Vec3::new(c[0], c[1], c[2]);
                s += w * c[3];
                let cos = v.dot(r);
                let w = if cos.abs() >= gate { w } else { 0.0 };
                total += w;
                acc += w.copysign(cos) * v;
            }
        } else {
            for (i, w) in trilinear(self.dims, p) {
                let w = w as f32;
                let slots = &self.cells[i * k..(i + 1) * k];
                s += w * slots[0][3];
                let mut best = glam::Vec3::new(slots[0][0], slots[0][1], slots[0][2]);
                let mut cos = best.dot(r);
                for c in &slots[1..] {
                    let v = glam::Vec3::new(c[0], c[1], c[2]);
                    let d = v.dot(r);
                    if d.abs() > cos.abs() {
                        (best, cos) = (v, d);
                    }
                }
                if cos.abs() >= gate && best != glam::Vec3::ZERO {
                    total += w;
                    acc += w.copysign(cos) * best;
                }
            }
        }
        let n = acc.length();
        (total >= MIN_TOTAL_WEIGHT && n > 0.0 && n.is_finite())
            .then(|| FieldSample { direction: (acc / n).as_dvec3(), fa: f64::from(s) })
    }
    /// One start per peak of the voxel nearest the seed, each followed through the interpolation.
    fn seed_samples(&self, p: DVec3, out: &mut Vec<FieldSample>) {
        out.clear();
        let v = self.nearest_voxel(p);
        for peak in self.peaks_at(v).filter(|d| *d != DVec3::ZERO) {
            if let Some(s) = self.sample(p, peak) {
                let direction = if s.direction.dot(peak) < 0.0 { -s.direction } else { s.direction };
                out.push(FieldSample { direction, ..s });
            }
        }
    }
    fn tensor(&self, p: DVec3) -> LowerTri {
        let Some(t) = &self.tensors else { return [0.0; 6] };
        let mut out = [0.0; 6];
        for (i, w) in trilinear(self.dims, p) {
            for (o, x) in out.iter_mut().zip(&t[i]) {
                *o += w * f64::from(*x);
            }
        }
        out
    }
}

/// An analytic field whose integral curves are circles around the z axis through `centre` (voxel
/// coordinates, 1 mm voxels): the direction is the tangent `(-y, x, 0) / r`. Used to measure the
/// integrators' convergence orders against exact streamlines.
#[derive(Clone, Copy, Debug)]
pub struct CircleField {
    /// Grid size in voxels, (X, Y, Z).
    pub dims: [usize; 3],
    /// A point on the axis of the circles, in voxel coordinates.
    pub centre: DVec3,
}

impl DirectionField for CircleField {
    fn dims(&self) -> [usize; 3] {
        self.dims
    }
    fn voxel_size(&self) -> DVec3 {
        DVec3::ONE
    }
    fn sample(&self, p: DVec3, _reference: DVec3) -> Option<FieldSample> {
        let d = p - self.centre;
        let t = DVec3::new(-d.y, d.x, 0.0);
        let n = t.length();
        (n > 0.0).then(|| FieldSample { direction: t / n, fa: 1.0 })
    }
    fn tensor(&self, p: DVec3) -> LowerTri {
        let Some(s) = self.sample(p, DVec3::ZERO) else { return [0.0; 6] };
        let e1 = s.direction;
        from_eigen(&Eigen { values: [1.7e-3, 0.3e-3, 0.3e-3], vectors: [e1, DVec3::Z.cross(e1), DVec3::Z] })
    }
}
