//! The barycentric transfer function of tensor splatting (SEEDS.md §1): colour and opacity from a tensor's
//! Westin shape measures (cl, cp, cs), a point in the triangle whose corners are pure linear, planar and
//! spherical tensors. A Gaussian bump with a movable centre and width gives the opacity (threshold, invert);
//! the corner colours blend barycentrically; "stretch" maps each measure to its data range first. Only
//! colours and opacities depend on it, so editing it needs no re-projection or re-sort.

use glam::{DVec2, DVec3};

use super::metrics::{WestinDenominator, westin};

/// Corners of the triangle in the plane (equilateral, unit side): linear, planar, spherical.
const CORNERS: [DVec2; 3] = [DVec2::new(0.0, 0.0), DVec2::new(1.0, 0.0), DVec2::new(0.5, 0.866_025_403_784_438_6)];

/// The transfer function's parameters.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct BarycentricTf {
    /// Denominator of the Westin measures that place a tensor in the triangle; defaults to the trace.
    pub denominator: WestinDenominator,
    /// Centre of the opacity bump as (cl, cp, cs) (normalised to sum 1).
    pub centre: [f64; 3],
    /// Standard deviation of the bump, in units of the triangle's side.
    pub width: f64,
    /// Opacities below this become 0.
    pub threshold: f64,
    /// Opacity `1 - bump` instead of `bump`.
    pub invert: bool,
    /// Map each measure to its data range before use.
    pub stretch: bool,
    /// Linear RGB at the linear, planar and spherical corners.
    pub corners: [[f64; 3]; 3],
    /// Largest opacity.
    pub opacity: f64,
}

impl Default for BarycentricTf {
    /// Emphasises linear tensors: bump at the linear corner, green-yellow-red corners as Westin colouring.
    fn default() -> Self {
        Self {
            denominator: WestinDenominator::Trace,
            centre: [1.0, 0.0, 0.0],
            width: 0.35,
            threshold: 0.02,
            invert: false,
            stretch: false,
            corners: [[0.1, 0.8, 0.1], [0.9, 0.8, 0.1], [0.8, 0.1, 0.1]],
            opacity: 1.0,
        }
    }
}

/// Per-measure (min, max) over data, for stretching.
pub type Ranges = [(f64, f64); 3];

/// The data range of each measure over a set of (cl, cp, cs).
pub fn ranges(samples: &[[f64; 3]]) -> Ranges {
    let mut r = [(f64::INFINITY, f64::NEG_INFINITY); 3];
    for s in samples {
        for k in 0..3 {
            if s[k].is_finite() {
                r[k] = (r[k].0.min(s[k]), r[k].1.max(s[k]));
            }
        }
    }
    r.map(|(lo, hi)| if lo <= hi { (lo, hi) } else { (0.0, 1.0) })
}

impl BarycentricTf {
    /// The measures of eigenvalues `l` (largest first) under this function's denominator.
    pub fn measures(&self, l: &[f64; 3]) -> [f64; 3] {
        westin(l, self.denominator)
    }

    /// Colour (linear RGB) and opacity of a tensor with measures `w`; `ranges` is used when stretching.
    pub fn eval(&self, w: [f64; 3], ranges: Option<&Ranges>) -> (DVec3, f64) {
        let mut w = w.map(|v| if v.is_finite() { v.max(0.0) } else { 0.0 });
        if self.stretch
            && let Some(r) = ranges
        {
            for k in 0..3 {
                let span = r[k].1 - r[k].0;
                w[k] = if span > 0.0 { ((w[k] - r[k].0) / span).clamp(0.0, 1.0) } else { 0.0 };
            }
        }
        let total: f64 = w.iter().sum();
        if total <= 0.0 {
            return (DVec3::ZERO, 0.0);
        }
        let w = w.map(|v| v / total);
        let c_total: f64 = self.centre.iter().map(|v| v.max(0.0)).sum::<f64>().max(1e-12);
        let c = self.centre.map(|v| v.max(0.0) / c_total);
        let p = CORNERS[0] * w[0] + CORNERS[1] * w[1] + CORNERS[2] * w[2];
        let q = CORNERS[0] * c[0] + CORNERS[1] * c[1] + CORNERS[2] * c[2];
        let bump = (-(p - q).length_squared() / (2.0 * self.width.max(1e-6).powi(2))).exp();
        let mut a = if self.invert { 1.0 - bump } else { bump } * self.opacity;
        if a < self.threshold {
            a = 0.0;
        }
        let colour = (0..3).map(|k| DVec3::from_array(self.corners[k]) * w[k]).sum();
        (colour, a)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corners_bump_invert_threshold_and_stretch() {
        let tf = BarycentricTf { threshold: 0.0, ..BarycentricTf::default() };
        // Pure shapes take their corner's colour; the bump peaks (opacity 1) at its centre.
        for k in 0..3 {
            let mut w = [0.0; 3];
            w[k] = 1.0;
            let (c, _) = tf.eval(w, None);
            assert!((c - DVec3::from_array(tf.corners[k])).length() < 1e-15);
        }
        assert!((tf.eval([1.0, 0.0, 0.0], None).1 - 1.0).abs() < 1e-15);
        // One side away (planar corner) with width 0.35: exp(-1 / (2 * 0.35^2)).
        let far = tf.eval([0.0, 1.0, 0.0], None).1;
        assert!((far - (-1.0 / (2.0 * 0.35f64.powi(2))).exp()).abs() < 1e-12);
        let inv = BarycentricTf { invert: true, ..tf };
        assert!(inv.eval([1.0, 0.0, 0.0], None).1.abs() < 1e-15);
        assert!((inv.eval([0.0, 1.0, 0.0], None).1 - (1.0 - far)).abs() < 1e-12);
        let cut = BarycentricTf { threshold: 0.5, ..tf };
        assert_eq!(cut.eval([0.0, 1.0, 0.0], None).1, 0.0);
        // Stretch: data spanning cl in [0.2, 0.6] maps 0.6 to the top of the range.
        let data = [[0.2, 0.5, 0.3], [0.6, 0.1, 0.3], [0.4, 0.3, 0.3]];
        let r = ranges(&data);
        assert_eq!(r[0], (0.2, 0.6));
        let st = BarycentricTf { stretch: true, ..tf };
        let (_, a) = st.eval([0.6, 0.1, 0.3], Some(&r));
        // Stretched to (1, 0, 0) after normalisation (cs has no spread, so 0): the bump's peak.
        assert!((a - 1.0).abs() < 1e-12, "{a}");
        // Degenerate input: no colour, no opacity, no NaN.
        assert_eq!(tf.eval([f64::NAN, 0.0, 0.0], None), (DVec3::ZERO, 0.0));
        assert_eq!(tf.eval([0.0; 3], None), (DVec3::ZERO, 0.0));
    }
}
