#!/usr/bin/env python3
"""DIPY's deterministic tensor tracking as one process, for `fascicle bench tracking` (timed from outside):

    python bench/dipy_track.py DWI BVAL BVEC SEED_MASK OUT.trk [THREADS]

Reads the DWI, fits DTI (WLS), takes the principal eigenvector as the one peak per voxel (`peaks_from_model`,
default sphere), seeds at the centre of every voxel of SEED_MASK (`seeds_from_mask`, density 1), tracks with EuDX
(`eudx_tracking`: Euler, 0.5 mm, FA > 0.2, 60 degrees, max length 250 mm) and writes OUT.trk. Needs dipy==1.12.1;
never needed by the test suite.
"""

import sys
import time

import nibabel as nib
import numpy as np
from dipy.core.gradients import gradient_table
from dipy.data import default_sphere
from dipy.direction import peaks_from_model
from dipy.io.gradients import read_bvals_bvecs
from dipy.io.stateful_tractogram import Space, StatefulTractogram
from dipy.io.streamline import save_trk
from dipy.reconst.dti import TensorModel
from dipy.tracking.stopping_criterion import ThresholdStoppingCriterion
from dipy.tracking.tracker import eudx_tracking
from dipy.tracking.utils import seeds_from_mask


def main(dwi, bval, bvec, seed_mask, out, threads=0):
    img = nib.load(dwi)
    data = np.asarray(img.dataobj, dtype=np.float64)
    bvals, bvecs = read_bvals_bvecs(bval, bvec)
    gtab = gradient_table(bvals, bvecs=np.nan_to_num(bvecs))
    model = TensorModel(gtab, fit_method="WLS")
    fa = model.fit(data).fa
    pam = peaks_from_model(model, data, default_sphere, relative_peak_threshold=0.5, min_separation_angle=25,
                           mask=fa > 0.2, npeaks=1)
    seeds = seeds_from_mask(np.asarray(nib.load(seed_mask).dataobj) > 0, img.affine, density=1)
    sc = ThresholdStoppingCriterion(fa, 0.2)
    t = time.perf_counter()
    streamlines = list(eudx_tracking(seeds, sc, img.affine, pam=pam, step_size=0.5, max_angle=60, max_len=250,
                                     nbr_threads=threads))
    t_track = time.perf_counter() - t
    save_trk(StatefulTractogram(streamlines, img, Space.RASMM), out, bbox_valid_check=False)
    print(f"{len(seeds)} seeds, {len(streamlines)} streamlines, {sum(len(s) for s in streamlines)} points")
    print(f"tracking {t_track:.3f} s (eudx_tracking alone)")


if __name__ == "__main__":
    a = sys.argv[1:]
    main(*a[:5], threads=int(a[5]) if len(a) > 5 else 0)
