#!/usr/bin/env python3
"""Reference arrays for ODF peak extraction and peak tracking, computed by DIPY 1.12.1 on the ring/crossing phantom.

Usage (in a venv with `pip install dipy==1.12.1`; never needed by the test suite, which reads the outputs):

    python bench/make_peak_reference.py

Writes into data/reference/peaks/ (see data/reference/README.md, section peaks/) and the default sphere's vertices and
edges into core/data/spheres/.
"""

import gzip
import json
import os

import nibabel as nib
import numpy as np
from dipy.core.gradients import gradient_table
from dipy.data import default_sphere
from dipy.direction import peaks_from_model
from dipy.io.gradients import read_bvals_bvecs
from dipy.reconst.shm import CsaOdfModel
from dipy.tracking.stopping_criterion import ThresholdStoppingCriterion
from dipy.tracking.tracker import eudx_tracking
from dipy.tracking.utils import seeds_from_mask

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
OUT = os.path.join(ROOT, "data", "reference", "peaks")
L_MAX, REL, SEP, NPEAKS = 6, 0.5, 25.0, 5
GFA_STOP, STEP, ANGLE, CUT_X = 0.25, 0.5, 60.0, 24


def save_gz(path, array):
    with gzip.open(path, "wb", compresslevel=9) as f:
        np.save(f, array)


def main():
    os.makedirs(OUT, exist_ok=True)
    spheres = os.path.join(ROOT, "core", "data", "spheres")
    np.savetxt(os.path.join(spheres, "default_sphere_vertices.txt"), default_sphere.vertices, fmt="%.17g")
    np.savetxt(os.path.join(spheres, "default_sphere_edges.txt"), default_sphere.edges, fmt="%d")

    ph = os.path.join(ROOT, "data", "phantom", "phantom_ring_cross")
    img = nib.load(ph + ".nii.gz")
    data = np.asarray(img.dataobj, dtype=np.float64)
    bvals, bvecs = read_bvals_bvecs(ph + ".bval", ph + ".bvec")
    gtab = gradient_table(bvals, bvecs=bvecs)
    model = CsaOdfModel(gtab, L_MAX, smooth=0.006)
    pam = peaks_from_model(model, data, default_sphere, relative_peak_threshold=REL, min_separation_angle=SEP,
                           npeaks=NPEAKS, return_sh=True, sh_order_max=L_MAX)
    pre = os.path.join(OUT, f"phantom_csa_l{L_MAX}")
    # Directions are sphere vertices: the indices carry them (checked here), values in float32, gzipped.
    has = pam.peak_indices >= 0
    assert np.array_equal(pam.peak_dirs[has], default_sphere.vertices[pam.peak_indices[has]])
    assert not np.any(pam.peak_dirs[~has])
    save_gz(pre + "_peak_indices.npy.gz", pam.peak_indices.astype(np.int16))
    save_gz(pre + "_peak_values.npy.gz", pam.peak_values.astype(np.float32))
    save_gz(pre + "_gfa.npy.gz", pam.gfa.astype(np.float32))

    # Deterministic tracking on the same peaks: DIPY's EuDX, stopping on GFA > 0.25 (bundles 0.37-0.71, background
    # below 0.18). The half x < 24 is cut from the stopping map, so ring streamlines end instead of looping (EuDX
    # drops any streamline longer than max_len; a loop always is). Seeds: every voxel of the stopping mask.
    stop = pam.gfa.copy()
    stop[:CUT_X] = 0
    mask = stop > GFA_STOP
    seeds = seeds_from_mask(mask, img.affine, density=1)
    sc = ThresholdStoppingCriterion(stop, GFA_STOP)
    streamlines = list(eudx_tracking(seeds, sc, img.affine, pam=pam, step_size=STEP, max_angle=ANGLE))
    inv = np.linalg.inv(img.affine)
    density = np.zeros(mask.shape)
    for s in streamlines:
        v = np.rint(s @ inv[:3, :3].T + inv[:3, 3]).astype(int)
        v = np.unique(v[np.all((v >= 0) & (v < mask.shape), axis=1)], axis=0)
        density[tuple(v.T)] += 1
    save_gz(pre + "_eudx_density.npy.gz", density.astype(np.float32))
    lengths = [len(s) for s in streamlines]
    with open(pre + "_eudx.json", "w") as f:
        json.dump({"l_max": L_MAX, "relative_peak_threshold": REL, "min_separation_angle": SEP, "npeaks": NPEAKS,
                   "sphere": "default_sphere (repulsion724 hemisphere, 362 vertices)",
                   "stop": f"gfa > {GFA_STOP}, zero where x < {CUT_X}", "step_size": STEP, "max_angle": ANGLE,
                   "seeds": int(len(seeds)), "streamlines": len(streamlines), "points": int(sum(lengths)),
                   "mean_points": float(np.mean(lengths))}, f, indent=1)
    counts = np.count_nonzero(np.linalg.norm(pam.peak_dirs, axis=-1) > 0, axis=-1)
    print("peak counts:", np.bincount(counts.ravel()), "gfa range", pam.gfa.min(), pam.gfa.max(),
          "seeds", len(seeds), "streamlines", len(streamlines), "points", sum(len(s) for s in streamlines))


if __name__ == "__main__":
    main()
