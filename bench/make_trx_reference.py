"""Reference TRX files for Fascicle's tests (data/tracts/tracks300_*.trx, data/reference/trx/), written by
trx-python 0.6 (nibabel 5.4.2) from nibabel's reading of data/tracts/tracks300.trk. Run from the repository root with trx-python and
nibabel installed (pip install trx-python).
"""
import zipfile
import nibabel as nib
import numpy as np
from trx import trx_file_memmap as tmm

trk = nib.streamlines.load("data/tracts/tracks300.trk")
sl = trk.streamlines
pts = np.asarray(sl._data, dtype=np.float64)
lengths = np.asarray(sl._lengths, dtype=np.uint32)
offsets = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.uint64)
hdr = trk.header
dims = [int(d) for d in hdr["dimensions"]]
vox2ras = np.asarray(hdr["voxel_to_rasmm"], dtype=float)

def make(pos_dtype, off_dtype, with_data):
    t = tmm.TrxFile(nb_vertices=len(pts), nb_streamlines=len(lengths))
    t.header = {"DIMENSIONS": dims, "VOXEL_TO_RASMM": vox2ras.tolist(), "NB_VERTICES": int(len(pts)), "NB_STREAMLINES": int(len(lengths))}
    t.streamlines._data = pts.astype(pos_dtype)
    t.streamlines._offsets = offsets.astype(off_dtype)
    t.streamlines._lengths = lengths
    if with_data:
        t.data_per_streamline = {"length_mm": np.array([np.linalg.norm(np.diff(s, axis=0), axis=1).sum() for s in sl], dtype=np.float32).reshape(-1, 1)}
        t.data_per_vertex = {"z_mm": nib.streamlines.ArraySequence(
            [np.asarray(s[:, 2:3], dtype=np.float32) for s in sl])}
        t.groups = {"first_ten": np.arange(10, dtype=np.uint32)}
    return t

tmm.save(make(np.float16, np.uint64, True), "data/tracts/tracks300_f16.trx")
tmm.save(make(np.float32, np.uint32, False), "data/tracts/tracks300_f32_deflate.trx", compression_standard=zipfile.ZIP_DEFLATED)
for f in ["data/tracts/tracks300_f16.trx", "data/tracts/tracks300_f32_deflate.trx"]:
    z = zipfile.ZipFile(f)
    print(f, [(i.filename, i.file_size, i.compress_type) for i in z.infolist()])
    back = tmm.load(f)
    print(" streamlines", len(back.streamlines), "vertices", len(back.streamlines._data), back.streamlines._data.dtype)
np.save("data/reference/trx/tracks300_f16_positions.npy", pts.astype(np.float16).astype(np.float64))
