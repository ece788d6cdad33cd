//! Streamline compression against DIPY 1.12's `compress_streamlines` (data/reference/compress, written by
//! bench/make_compress_reference.py) on two real tractograms at three tolerances: the same points kept.

mod common;

use fascicle_core::compress::{Compression, compress};
use fascicle_core::io::Tractogram;

#[test]
fn compression_keeps_the_points_dipy_keeps() {
    let cases = [("tracks300", "tracts/tracks300.trk"), ("small_64D_eudx", "reference/tracking/small_64D_eudx.trk")];
    for (name, file) in cases {
        let t = Tractogram::read(common::data(file)).unwrap();
        for tol in ["0.01", "0.1", "0.5"] {
            let c = compress(&t, Compression { tolerance_mm: tol.parse().unwrap(), max_segment_mm: 10.0 });
            let (_, lengths) = common::npy(&format!("reference/compress/{name}_tol{tol}_lengths.npy"));
            let (_, points) = common::npy(&format!("reference/compress/{name}_tol{tol}_points.npy"));
            let ours: Vec<f64> = (0..c.n_streamlines()).map(|i| c.streamline(i).len() as f64).collect();
            assert_eq!(ours, lengths, "{name} at {tol} mm: points per streamline");
            let worst = c
                .points
                .iter()
                .zip(points.chunks(3))
                .map(|(p, q)| (p.as_dvec3() - glam::DVec3::from_slice(q)).abs().max_element())
                .fold(0.0, f64::max);
            // The same points of the file, read as float32 by both.
            assert!(worst < 1e-5, "{name} at {tol} mm: kept points differ by {worst} mm");
            assert!(c.points.len() < t.points.len(), "{name} at {tol} mm: nothing dropped");
        }
    }
}
