#!/usr/bin/env python3
"""Time DIPY on the same inputs as `fascicle bench fits`, for the side-by-side table of `fascicle bench all`.

Usage (in a venv with `pip install dipy==1.12.1`; DIPY is never needed by the test suite):

    python bench/compare_dipy.py DIR

DIR holds `phantom_large.nii.gz`, `.bval`, `.bvec` as `fascicle bench all --report DIR` (or
`fascicle bench fits --write-phantom DIR`) writes them. Writes `DIR/dipy.csv` with the columns
`method,n,param,frame_ms,error` (frame_ms = wall time of the whole operation; error empty), one row per
operation, the same method names as Fascicle's rows: dti-wls, dti-ols, csa-l6, track-euler.
"""

import csv
import os
import sys
import time

import numpy as np
import nibabel as nib
from dipy.core.gradients import gradient_table
from dipy.data import default_sphere
from dipy.direction import peaks_from_model
from dipy.io.gradients import read_bvals_bvecs
from dipy.reconst.dti import TensorModel
from dipy.reconst.shm import CsaOdfModel
from dipy.tracking.stopping_criterion import ThresholdStoppingCriterion
from dipy.tracking.tracker import eudx_tracking
from dipy.tracking.utils import seeds_from_mask


def timed(f):
    t = time.perf_counter()
    out = f()
    return out, (time.perf_counter() - t) * 1e3


def main(d):
    img = nib.load(os.path.join(d, "phantom_large.nii.gz"))
    data = np.asarray(img.dataobj, dtype=np.float64)
    bvals, bvecs = read_bvals_bvecs(os.path.join(d, "phantom_large.bval"), os.path.join(d, "phantom_large.bvec"))
    gtab = gradient_table(bvals, bvecs=bvecs)
    nvox = int(np.prod(data.shape[:3]))
    rows = []
    wls, ms = timed(lambda: TensorModel(gtab, fit_method="WLS").fit(data))
    rows.append(("dti-wls", nvox, "whole volume", ms))
    _, ms = timed(lambda: TensorModel(gtab, fit_method="OLS").fit(data))
    rows.append(("dti-ols", nvox, "whole volume", ms))
    _, ms = timed(lambda: CsaOdfModel(gtab, 6, smooth=0.006).fit(data))
    rows.append(("csa-l6", nvox, "whole volume", ms))
    fa = wls.fa
    mask = fa > 0.3
    seeds = seeds_from_mask(mask, img.affine, density=1)

    def track():
        pam = peaks_from_model(TensorModel(gtab, fit_method="WLS"), data, default_sphere,
                               relative_peak_threshold=0.5, min_separation_angle=25, mask=fa > 0.2, npeaks=1)
        sc = ThresholdStoppingCriterion(fa, 0.2)
        return list(eudx_tracking(seeds, sc, img.affine, pam=pam, step_size=0.5, max_angle=60))

    sl, ms = timed(track)
    points = sum(len(s) for s in sl)
    rows.append(("track-euler", points, f"{len(seeds)} seeds; {len(sl)} streamlines; fit+peaks+track", ms))
    with open(os.path.join(d, "dipy.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["method", "n", "param", "frame_ms", "error"])
        for r in rows:
            w.writerow([r[0], r[1], r[2], f"{r[3]:.1f}", ""])
    for r in rows:
        print(f"{r[0]:12s} n={r[1]:>9} {r[3]:10.1f} ms  {r[2]}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else ".")
