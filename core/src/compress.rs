//! Streamline compression by linearisation (Presseau et al. 2015, "A new compression format for fiber
//! tracking datasets"; Rheault et al. 2015, "Real time interaction with millions of streamlines"): points
//! that lie within a tolerance of the straight segment that replaces them are dropped. The rule is DIPY's
//! `compress_streamlines` (checked against its output in `tests/compress.rs`), so a tolerance means the same
//! here as there. The viewer draws line layers compressed: on smooth tractography at 1 mm steps a 0.1 mm
//! tolerance keeps a third of the points or fewer, below a pixel at any zoom that shows a whole brain.

use glam::Vec3;

use crate::io::Tractogram;

/// How much a compressed streamline may differ from the original.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Compression {
    /// The largest distance of a dropped point from the line through the two kept points around it, mm.
    /// Default 0.1 (DIPY's advice for probabilistic streamlines; 0.01 for deterministic ones). 0 keeps every
    /// point that is not exactly collinear.
    pub tolerance_mm: f64,
    /// The longest segment the compression makes, mm. Default 10 (DIPY's default).
    pub max_segment_mm: f64,
}

impl Default for Compression {
    fn default() -> Self {
        Compression { tolerance_mm: 0.1, max_segment_mm: 10.0 }
    }
}

/// Appends to `kept` the indices (into `points`) of the points that compression keeps of one streamline: the
/// first and last always; a streamline of two points or fewer whole.
///
/// Walking forward from the last kept point `prev`, a candidate end `next` is accepted while every point
/// between lies within the tolerance of the line through `prev` and `next` and `next` is within the maximum
/// segment length of `prev`; otherwise the point before `next` is kept and becomes `prev`. Differences of
/// points are taken in `f32` (as the file stores them) and distances in `f64`, as DIPY does.
pub fn kept_points(points: &[Vec3], c: Compression, kept: &mut Vec<u32>) {
    let n = points.len();
    if n <= 2 {
        kept.extend(0..n as u32);
        return;
    }
    let diff = |a: usize, b: usize| (points[a] - points[b]).as_dvec3();
    // DIPY's test, `|chord x (curr - next)| / |chord| > tolerance`, is decided without a square root or a
    // division where the squares are clearly apart (relative margin far above their rounding), and computed
    // as DIPY does where they are close, so that every decision is DIPY's.
    let tol2 = c.tolerance_mm * c.tolerance_mm;
    let (above, below) = (1.0 + 1e-9, 1.0 - 1e-9);
    kept.push(0);
    let mut prev = 0;
    for next in 2..n {
        let chord = diff(next, prev);
        let chord2 = chord.length_squared();
        let bound = tol2 * chord2;
        let keep_before = chord2.sqrt() > c.max_segment_mm
            || (prev + 1..next).any(|curr| {
                if diff(curr, prev).length_squared() == 0.0 {
                    return false;
                }
                let cross2 = chord.cross(diff(curr, next)).length_squared();
                if chord2 > 0.0 && bound.is_normal() && cross2.is_finite() {
                    if cross2 > bound * above {
                        return true;
                    }
                    if cross2 < bound * below {
                        return false;
                    }
                }
                let d = cross2.sqrt() / chord2.sqrt();
                d.is_nan() || d > c.tolerance_mm
            });
        if keep_before {
            kept.push(next as u32 - 1);
            prev = next - 1;
        }
    }
    kept.push(n as u32 - 1);
}

/// `t` compressed streamline by streamline: the kept points with their per-point values; per-streamline
/// values unchanged.
pub fn compress(t: &Tractogram, c: Compression) -> Tractogram {
    let mut out = Tractogram::new();
    let mut keep = Vec::new();
    let mut all = Vec::new();
    for s in 0..t.n_streamlines() {
        let first = t.offsets[s];
        keep.clear();
        kept_points(t.streamline(s), c, &mut keep);
        all.extend(keep.iter().map(|k| first + *k as usize));
        out.points.extend(keep.iter().map(|k| t.points[first + *k as usize]));
        out.offsets.push(out.points.len());
    }
    out.scalars = t.scalars.iter().map(|(name, v)| (name.clone(), all.iter().map(|i| v[*i]).collect())).collect();
    out.properties = t.properties.clone();
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kept(points: &[Vec3], tolerance_mm: f64) -> Vec<u32> {
        let mut k = Vec::new();
        kept_points(points, Compression { tolerance_mm, max_segment_mm: 10.0 }, &mut k);
        k
    }

    #[test]
    fn a_straight_line_keeps_its_ends_and_a_point_per_maximum_segment() {
        let line: Vec<Vec3> = (0..25).map(|i| Vec3::new(i as f32, 0.0, 0.0)).collect();
        // Segments of at most 10 mm: 0-10, 10-20, 20-24.
        assert_eq!(kept(&line, 0.1), vec![0, 10, 20, 24]);
        assert_eq!(kept(&line[..2], 0.1), vec![0, 1]);
        assert!(kept(&[], 0.1).is_empty());
    }

    #[test]
    fn every_dropped_point_lies_within_the_tolerance_of_its_segment() {
        // A helix of radius 5 mm at 1 mm steps.
        let helix: Vec<Vec3> = (0..200)
            .map(|i| {
                let a = i as f32 * 0.2;
                Vec3::new(5.0 * a.cos(), 5.0 * a.sin(), 0.3 * i as f32)
            })
            .collect();
        for tol in [0.01, 0.1, 0.5] {
            let k = kept(&helix, tol);
            // The sagitta of two 0.2 rad steps on a 5 mm radius is 0.1 mm: 0.01 mm keeps every point.
            assert_eq!(k.len() < helix.len(), tol > 0.05, "tol {tol}: {} kept", k.len());
            for w in k.windows(2) {
                let (a, b) = (helix[w[0] as usize].as_dvec3(), helix[w[1] as usize].as_dvec3());
                for p in &helix[w[0] as usize + 1..w[1] as usize] {
                    let d = (b - a).cross(p.as_dvec3() - a).length() / (b - a).length();
                    assert!(d <= tol + 1e-6, "tol {tol}: a dropped point {d} mm off");
                }
            }
        }
    }
}
