"""Writes DIPY's streamline compression of two real tractograms as reference arrays.

DIPY 1.12's `compress_streamlines` (Presseau et al. 2015; Rheault et al. 2015) on `data/tracts/tracks300.trk`
(nibabel's test file) and `data/reference/tracking/small_64D_eudx.trk` (DIPY's EuDX), read in RAS+ mm by
nibabel, at three tolerances with DIPY's default 10 mm maximum segment length. Each case writes
`data/reference/compress/<name>_tol<tol>_{lengths,points}.npy` (float64 points and lengths, C order). Run from
the repository root with DIPY and nibabel installed: `python bench/make_compress_reference.py`.
"""

import os

import nibabel as nib
import numpy as np
from dipy.tracking.streamlinespeed import compress_streamlines

CASES = {
    "tracks300": "data/tracts/tracks300.trk",
    "small_64D_eudx": "data/reference/tracking/small_64D_eudx.trk",
}
OUT = "data/reference/compress"

os.makedirs(OUT, exist_ok=True)
for name, path in CASES.items():
    streamlines = [np.asarray(s, dtype=np.float32) for s in nib.streamlines.load(path).streamlines]
    for tol in ("0.01", "0.1", "0.5"):
        out = compress_streamlines(streamlines, tol_error=float(tol), max_segment_length=10.0)
        lengths = np.array([len(s) for s in out], dtype=np.float64)
        points = np.concatenate(out).astype(np.float64)
        np.save(f"{OUT}/{name}_tol{tol}_lengths.npy", lengths)
        np.save(f"{OUT}/{name}_tol{tol}_points.npy", points)
        print(name, tol, sum(len(s) for s in streamlines), "->", len(points))
