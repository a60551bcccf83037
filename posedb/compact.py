"""Rewriting a library so that nothing deleted is left in its bytes (`sitrelax db compact`).

HDF5 reuses or abandons the space of deleted objects but does not wipe it, so a deleted take's
notes, subject and frames, and a deleted pose's notes and rotations, stay readable in the file.
Compaction copies only what is live, object by object (every attribute with it: a skeleton's
`joint_map`, a take's tags) into a new file, and keeps of `/poses/rotations` only the rows
poses still use.
"""

from __future__ import annotations

import h5py
import numpy as np

from .posetable import PoseTable

_COPIED_GROUPS = ("skeletons", "takes", "bodies", "scenarios")


def compact_into(src: h5py.File, dst: h5py.File) -> None:
    """Writes the live content of library `src` into the new, empty file `dst`."""
    for key, value in src.attrs.items():
        dst.attrs[key] = value
    for name in _COPIED_GROUPS:
        if name in src:
            src.copy(src[name], dst, name=name)
        else:
            dst.create_group(name)
    table = PoseTable.read(src["poses"])
    old = src["poses"]["rotations"]
    starts, counts = table.cols["rotation_start"], table.cols["rotation_count"]
    rows = [old[s:s + c] for s, c in zip(starts.tolist(), counts.tolist())]
    new = np.concatenate(rows) if rows else np.zeros((0, 4), dtype=np.float32)
    poses = dst.create_group("poses")
    poses.create_dataset("rotations", data=new.astype(np.float32), maxshape=(None, 4),
                         chunks=(4096, 4), compression="gzip", compression_opts=4)
    if len(table):
        table.cols["rotation_start"] = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(
            np.int64)
        table.write(poses)
