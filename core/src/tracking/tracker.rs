//! The deterministic tracker: fixed-step integration of a [`DirectionField`] from seeds, both ways, with
//! FA, volume, mask, curvature and length stops.

use glam::{DMat3, DMat4, DVec3};
use rayon::prelude::*;

use super::field::{CircleField, DirectionField, in_grid};
use crate::dti::eigen::LowerTri;
use crate::error::{Error, Result};
use crate::io::Tractogram;

/// The integration scheme for `dp/ds = d(p)`, `s` the arc length in mm.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Integrator {
    /// Explicit Euler, first order (what DIPY's EuDX and `LocalTracking` do).
    Euler,
    /// Midpoint rule, second order.
    Rk2,
    /// Classical fourth-order Runge-Kutta.
    #[default]
    Rk4,
}

impl std::str::FromStr for Integrator {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_lowercase().as_str() {
            "euler" => Ok(Self::Euler),
            "rk2" | "midpoint" => Ok(Self::Rk2),
            "rk4" => Ok(Self::Rk4),
            _ => Err(Error::Param(format!("unknown integrator '{s}' (use rk4, rk2 or euler)"))),
        }
    }
}

/// Why one end of a streamline stopped (or why a seed gave none).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[repr(u8)]
pub enum StopReason {
    /// Interpolated FA fell below the threshold.
    LowFa,
    /// The next point (or an integration stage) left the grid.
    OutsideVolume,
    /// The next point left the tracking mask.
    OutsideMask,
    /// The direction turned more than `max_angle_deg` in one step.
    Angle,
    /// The half-streamline reached half of `max_length_mm`.
    MaxLength,
    /// No usable direction (isotropic, zero or non-finite tensor).
    NoDirection,
}

impl StopReason {
    /// Every reason, in declaration (and `Ord`) order.
    pub const ALL: [StopReason; 6] =
        [Self::LowFa, Self::OutsideVolume, Self::OutsideMask, Self::Angle, Self::MaxLength, Self::NoDirection];
    /// A short description for summaries: "FA below threshold", "left the volume", ...
    pub fn name(self) -> &'static str {
        match self {
            Self::LowFa => "FA below threshold",
            Self::OutsideVolume => "left the volume",
            Self::OutsideMask => "left the mask",
            Self::Angle => "turned too sharply",
            Self::MaxLength => "maximum length",
            Self::NoDirection => "no direction",
        }
    }
}

/// Why a seed produced no streamline.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Rejection {
    /// The seed is outside the grid or the mask.
    SeedOutside,
    /// FA at the seed is below the threshold, or there is no direction there.
    SeedBelowThreshold,
    /// Shorter than `min_length_mm` (or a single point).
    TooShort,
}

/// Tracking parameters. Defaults: RK4 at 0.5 mm, FA 0.2, 60 degrees, lengths 0..250 mm.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct TrackParams {
    /// Step length along the streamline, in mm (> 0). Defaults to 0.5.
    pub step_mm: f64,
    /// Tracks stop where the interpolated stopping scalar (FA; GFA or the like for a peak field) is at or below
    /// this; seeds at or below it are rejected. Defaults to 0.2.
    pub fa_threshold: f64,
    /// Largest turn between consecutive steps, in degrees, in (0, 180]. Defaults to 60.
    pub max_angle_deg: f64,
    /// The integration scheme. Defaults to [`Integrator::Rk4`].
    pub integrator: Integrator,
    /// Streamlines shorter than this (in mm, `(points - 1) · step_mm`) are rejected. Defaults to 0.
    pub min_length_mm: f64,
    /// Whole streamline; each half gets at most half of it.
    pub max_length_mm: f64,
}

impl Default for TrackParams {
    fn default() -> Self {
        Self {
            step_mm: 0.5,
            fa_threshold: 0.2,
            max_angle_deg: 60.0,
            integrator: Integrator::Rk4,
            min_length_mm: 0.0,
            max_length_mm: 250.0,
        }
    }
}

impl TrackParams {
    /// Checks the parameters, naming the first bad one.
    pub fn validate(&self) -> Result<()> {
        let bad = |what: &str, v: f64, rule: &str| Err(Error::Param(format!("{what} = {v}: {rule}")));
        if !(self.step_mm.is_finite() && self.step_mm > 0.0) {
            return bad("step", self.step_mm, "must be a positive number of mm");
        }
        if !self.fa_threshold.is_finite() {
            return bad("FA threshold", self.fa_threshold, "must be finite");
        }
        if !(self.max_angle_deg > 0.0 && self.max_angle_deg <= 180.0) {
            return bad("max angle", self.max_angle_deg, "must be in (0, 180] degrees");
        }
        if !(self.min_length_mm >= 0.0 && self.min_length_mm.is_finite()) {
            return bad("min length", self.min_length_mm, "must be >= 0 mm");
        }
        if self.max_length_mm.is_nan() || self.max_length_mm <= 0.0 {
            return bad("max length", self.max_length_mm, "must be > 0 mm");
        }
        if self.max_length_mm < self.min_length_mm {
            return bad("max length", self.max_length_mm, "must be at least the min length");
        }
        Ok(())
    }
}

/// Streamlines with what the hyperstreamline renderer and the summary need, in flat arrays.
#[derive(Clone, Debug, Default)]
pub struct Tracks {
    /// Points in world RAS+ mm, CSR offsets.
    pub tractogram: Tractogram,
    /// Per point, the interpolated tensor rotated into the world frame (`R T Rᵀ`, `R` the rotation of the
    /// affine), lower-triangular order, mm²/s.
    pub tensors: Vec<[f32; 6]>,
    /// Per streamline, why its first and last point ended the track.
    pub ends: Vec<[StopReason; 2]>,
    /// Per streamline, the index of its seed.
    pub seed_index: Vec<u32>,
    /// Seeds that gave no streamline, with why.
    pub rejected: Vec<(u32, Rejection)>,
}

impl Tracks {
    /// Total points over all streamlines.
    pub fn n_points(&self) -> usize {
        self.tractogram.points.len()
    }
    /// How many streamline ends stopped for each reason.
    pub fn stop_counts(&self) -> Vec<(StopReason, usize)> {
        StopReason::ALL
            .iter()
            .map(|&r| (r, self.ends.iter().flatten().filter(|&&e| e == r).count()))
            .filter(|&(_, n)| n > 0)
            .collect()
    }
    /// How many seeds were rejected for each reason.
    pub fn rejection_counts(&self) -> Vec<(Rejection, usize)> {
        let mut out: Vec<(Rejection, usize)> = Vec::new();
        for &(_, r) in &self.rejected {
            match out.iter_mut().find(|(k, _)| *k == r) {
                Some((_, n)) => *n += 1,
                None => out.push((r, 1)),
            }
        }
        out.sort();
        out
    }
}

/// Seeds per parallel work item.
const SEED_BLOCK: usize = 64;

/// The tracker: a field, where it sits in the world, an optional mask, and the parameters.
pub struct Tracker<'a, F: DirectionField> {
    /// The direction field followed, sampled in voxel coordinates.
    pub field: &'a F,
    /// The field grid's affine, voxel indices to world RAS+ mm: output points and tensors go through it.
    pub world_from_voxel: DMat4,
    /// One entry per voxel (NIfTI order); tracks stop on leaving it (nearest voxel).
    pub mask: Option<&'a [bool]>,
    /// Step, stopping and length parameters (validated by [`Tracker::new`]).
    pub params: TrackParams,
    /// Record the field's tensor at every output point ([`Tracks::tensors`]; default true). The
    /// hyperstreamline renderer needs them; a plain tractogram does not, and they cost a blend and a
    /// rotation per point.
    pub record_tensors: bool,
}

/// One half-streamline's points (reused across seeds: no per-point allocation).
#[derive(Default)]
struct Half {
    pts: Vec<DVec3>,
}

impl<'a, F: DirectionField> Tracker<'a, F> {
    /// A tracker with no mask, recording tensors; `Err` for invalid `params` or a singular or non-finite affine.
    pub fn new(field: &'a F, world_from_voxel: DMat4, params: TrackParams) -> Result<Self> {
        params.validate()?;
        if !world_from_voxel.is_finite() || world_from_voxel.determinant() == 0.0 {
            return Err(Error::Param("the voxel-to-world affine is singular or not finite".into()));
        }
        Ok(Self { field, world_from_voxel, mask: None, params, record_tensors: true })
    }

    /// Adds a tracking mask (one bool per voxel).
    pub fn with_mask(mut self, mask: &'a [bool]) -> Result<Self> {
        let n: usize = self.field.dims().iter().product();
        if mask.len() != n {
            return Err(Error::Shape(format!("the tracking mask has {} voxels, the field {n}", mask.len())));
        }
        self.mask = Some(mask);
        Ok(self)
    }

    /// Whether to record tensors at output points (see [`Tracker::record_tensors`]).
    pub fn with_tensors(mut self, record: bool) -> Self {
        self.record_tensors = record;
        self
    }

    fn in_mask(&self, p: DVec3) -> bool {
        let Some(mask) = self.mask else { return true };
        let [nx, ny, nz] = self.field.dims();
        let r = p.round();
        let (x, y, z) =
            (r.x.clamp(0.0, nx as f64 - 1.0), r.y.clamp(0.0, ny as f64 - 1.0), r.z.clamp(0.0, nz as f64 - 1.0));
        mask[x as usize + nx * (y as usize + ny * z as usize)]
    }

    /// The field's direction at `p`, sign-aligned with `prev`; `Err` with the reason when there is none.
    #[inline]
    fn dir(&self, p: DVec3, prev: DVec3) -> std::result::Result<DVec3, StopReason> {
        if !in_grid(self.field.dims(), p) {
            return Err(StopReason::OutsideVolume);
        }
        let s = self.field.sample(p, prev).ok_or(StopReason::NoDirection)?;
        Ok(if s.direction.dot(prev) < 0.0 { -s.direction } else { s.direction })
    }

    /// One step from `p` whose field direction `k1` is known (already sign-aligned): the step direction
    /// (not normalised: a Runge-Kutta combination of unit vectors).
    #[inline]
    fn step(&self, p: DVec3, k1: DVec3, h_vox: DVec3) -> std::result::Result<DVec3, StopReason> {
        Ok(match self.params.integrator {
            Integrator::Euler => k1,
            Integrator::Rk2 => self.dir(p + 0.5 * h_vox * k1, k1)?,
            Integrator::Rk4 => {
                let k2 = self.dir(p + 0.5 * h_vox * k1, k1)?;
                let k3 = self.dir(p + 0.5 * h_vox * k2, k2)?;
                let k4 = self.dir(p + h_vox * k3, k3)?;
                (k1 + 2.0 * (k2 + k3) + k4) / 6.0
            }
        })
    }

    /// Traces from `p0`, where the field direction is `d0` (unit, sign chosen), until a stop; pushes the
    /// points after `p0` into `half.pts`. The sample that checks FA at a new point also gives the next
    /// step's first stage, so Euler costs one field sample per point and RK4 four.
    fn trace(&self, p0: DVec3, d0: DVec3, half: &mut Half) -> StopReason {
        half.pts.clear();
        let h = self.params.step_mm;
        let h_vox = h / self.field.voxel_size();
        let cos_max = self.params.max_angle_deg.to_radians().cos();
        let max_steps = (0.5 * self.params.max_length_mm / h + 1e-9).floor() as usize;
        let (mut p, mut d, mut k1) = (p0, d0, d0);
        for _ in 0..max_steps {
            let dn = match self.step(p, k1, h_vox) {
                Ok(v) => v,
                Err(r) => return r,
            };
            let len = dn.length();
            if !(len > 0.0 && len.is_finite()) {
                return StopReason::NoDirection;
            }
            if dn.dot(d) < cos_max * len {
                return StopReason::Angle;
            }
            let next = p + h_vox * dn;
            if !in_grid(self.field.dims(), next) {
                return StopReason::OutsideVolume;
            }
            if !self.in_mask(next) {
                return StopReason::OutsideMask;
            }
            d = dn / len;
            let s = match self.field.sample(next, d) {
                Some(s) if s.fa > self.params.fa_threshold => s,
                Some(_) => return StopReason::LowFa,
                None => return StopReason::NoDirection,
            };
            half.pts.push(next);
            p = next;
            k1 = if s.direction.dot(d) < 0.0 { -s.direction } else { s.direction };
        }
        StopReason::MaxLength
    }

    /// Tracks one seed (voxel coordinates) both ways along each of its start directions (one for a tensor
    /// field, one per peak for a peak field): calls `emit` with the joined points (voxel coordinates) and
    /// end reasons of each streamline, and returns how many there were, or why there is none.
    fn track_seed(
        &self,
        seed: DVec3,
        scratch: &mut Scratch,
        emit: &mut impl FnMut(&[DVec3], [StopReason; 2]),
    ) -> std::result::Result<usize, Rejection> {
        if !seed.is_finite() || !in_grid(self.field.dims(), seed) || !self.in_mask(seed) {
            return Err(Rejection::SeedOutside);
        }
        self.field.seed_samples(seed, &mut scratch.starts);
        if !scratch.starts.iter().any(|s| s.fa > self.params.fa_threshold) {
            return Err(Rejection::SeedBelowThreshold);
        }
        let mut n = 0;
        for k in 0..scratch.starts.len() {
            let d0 = scratch.starts[k].direction;
            let end_f = self.trace(seed, d0, &mut scratch.fwd);
            let end_b = self.trace(seed, -d0, &mut scratch.bwd);
            let line = &mut scratch.line;
            line.clear();
            line.extend(scratch.bwd.pts.iter().rev());
            line.push(seed);
            line.extend(scratch.fwd.pts.iter());
            let length = (line.len() - 1) as f64 * self.params.step_mm;
            if line.len() >= 2 && length >= self.params.min_length_mm {
                emit(line, [end_b, end_f]);
                n += 1;
            }
        }
        if n == 0 { Err(Rejection::TooShort) } else { Ok(n) }
    }

    /// Tracks one seed (voxel coordinates) both ways, in f64 voxel coordinates: the points from one end to
    /// the other and why each end stopped (the first streamline where the seed has several directions), or
    /// why the seed gave none.
    pub fn track_one(&self, seed: DVec3) -> std::result::Result<(Vec<DVec3>, [StopReason; 2]), Rejection> {
        let mut first = None;
        self.track_seed(seed, &mut Scratch::default(), &mut |line, ends| {
            first.get_or_insert_with(|| (line.to_vec(), ends));
        })?;
        Ok(first.expect("track_seed emitted at least one streamline"))
    }

    /// Tracks every seed (voxel coordinates) in parallel. The output order is the seed order whatever the
    /// number of threads.
    pub fn run(&self, seeds_vox: &[DVec3]) -> Tracks {
        self.run_with_progress(seeds_vox, &|_| {})
    }

    /// [`Tracker::run`], calling `progress(n)` from worker threads as each block of `n` seeds is done.
    pub fn run_with_progress(&self, seeds_vox: &[DVec3], progress: &(dyn Fn(usize) + Sync)) -> Tracks {
        let rot = crate::linalg::polar_rotation(DMat3::from_mat4(self.world_from_voxel));
        let blocks: Vec<Tracks> = seeds_vox
            .par_chunks(SEED_BLOCK)
            .enumerate()
            .map_init(Scratch::default, |scratch, (b, chunk)| {
                let mut t = Tracks { tractogram: Tractogram::new(), ..Default::default() };
                for (k, &seed) in chunk.iter().enumerate() {
                    let index = (b * SEED_BLOCK + k) as u32;
                    let mut emit = |line: &[DVec3], ends| {
                        let a = &self.world_from_voxel;
                        t.tractogram.points.extend(line.iter().map(|&p| a.transform_point3(p).as_vec3()));
                        if self.record_tensors {
                            t.tensors.extend(line.iter().map(|&p| rotate(&self.field.tensor(p), rot)));
                        }
                        t.tractogram.offsets.push(t.tractogram.points.len());
                        t.ends.push(ends);
                        t.seed_index.push(index);
                    };
                    if let Err(r) = self.track_seed(seed, scratch, &mut emit) {
                        t.rejected.push((index, r));
                    }
                }
                progress(chunk.len());
                t
            })
            .collect();
        concat(blocks)
    }
}

/// Per-worker buffers, reused across seeds: no allocation per point.
#[derive(Default)]
struct Scratch {
    fwd: Half,
    bwd: Half,
    line: Vec<DVec3>,
    starts: Vec<super::field::FieldSample>,
}

/// `R T Rᵀ` as f32, lower-triangular.
/// The world-frame tensors (lower-triangular) of `field` at world points `points` (RAS+ mm): what the
/// tracker records per point, for streamlines that come from a file. Points outside the grid get the zero
/// tensor (a hyperstreamline is then circular there).
pub fn tensors_at<F: DirectionField>(field: &F, world_from_voxel: DMat4, points: &[glam::Vec3]) -> Vec<[f32; 6]> {
    let voxel_from_world = world_from_voxel.inverse();
    let rot = crate::linalg::polar_rotation(DMat3::from_mat4(world_from_voxel));
    points
        .par_iter()
        .map(|p| {
            let v = voxel_from_world.transform_point3(p.as_dvec3());
            if in_grid(field.dims(), v) { rotate(&field.tensor(v), rot) } else { [0.0; 6] }
        })
        .collect()
}

fn rotate(t: &LowerTri, r: DMat3) -> [f32; 6] {
    let m = DMat3::from_cols_array(&[t[0], t[1], t[3], t[1], t[2], t[4], t[3], t[4], t[5]]);
    let w = r * m * r.transpose();
    [w.x_axis.x, w.x_axis.y, w.y_axis.y, w.x_axis.z, w.y_axis.z, w.z_axis.z].map(|v| v as f32)
}

fn concat(blocks: Vec<Tracks>) -> Tracks {
    let n_pts = blocks.iter().map(|b| b.tractogram.points.len()).sum();
    let mut out = Tracks { tractogram: Tractogram::new(), ..Default::default() };
    out.tractogram.points.reserve(n_pts);
    out.tensors.reserve(n_pts);
    for b in blocks {
        let base = out.tractogram.points.len();
        out.tractogram.points.extend_from_slice(&b.tractogram.points);
        out.tractogram.offsets.extend(b.tractogram.offsets[1..].iter().map(|o| o + base));
        out.tensors.extend_from_slice(&b.tensors);
        out.ends.extend_from_slice(&b.ends);
        out.seed_index.extend_from_slice(&b.seed_index);
        out.rejected.extend_from_slice(&b.rejected);
    }
    out
}

impl CircleField {
    /// The convergence experiment: a tracker and seed that trace one full turn of the circle of radius `r`
    /// (two half turns of `n_half` steps from the seed, which both end at the antipode `exact`).
    pub fn one_turn(
        &self,
        r: f64,
        n_half: usize,
        integrator: Integrator,
    ) -> crate::Result<(Tracker<'_, Self>, DVec3, DVec3)> {
        let h = std::f64::consts::PI * r / n_half.max(1) as f64;
        let params = TrackParams {
            step_mm: h,
            integrator,
            max_angle_deg: 90.0,
            max_length_mm: 2.0 * std::f64::consts::PI * r + h / 2.0,
            ..Default::default()
        };
        let tracker = Tracker::new(self, glam::DMat4::IDENTITY, params)?;
        Ok((tracker, self.centre + DVec3::new(r, 0.0, 0.0), self.centre - DVec3::new(r, 0.0, 0.0)))
    }
}
