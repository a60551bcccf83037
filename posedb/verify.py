"""Checking a pose library before it is changed (`sitrelax db check`).

A quick check reads every object's metadata, every skeleton and the pose table, and checks
that they agree: each take's skeleton exists and its arrays have one row per frame and the
skeleton's widths, each pose's take and frame exist and its rotation rows lie inside
`/poses/rotations`, and the notes offsets cover the notes. It also checks the values that
readers divide by or print: each take's frame time (seconds, as a BVH file may give it), each
skeleton's offsets and length unit, each pose's supports (bits of `schema.SUPPORT_BITS` only),
root position, placement (all numbers or all NaN) and creation time, and every other number
stored as an attribute (finite). A full check also reads every chunk of every dataset, so a
flipped bit in compressed data (which zlib's checksum catches) is found, and checks that the
arrays are finite.

`pose_table_problems` is also what `PoseLibrary` checks its index by when it opens a library.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from . import schema
from .posetable import PoseTable

_STORAGE = (OSError, KeyError, RuntimeError, ValueError, TypeError, UnicodeDecodeError)
_TAKE_ARRAYS = ("channels", "local_rotations", "root_positions", "frame_indices")


def _read_all(ds: h5py.Dataset, name: str, problems: list[str], *,
              quaternions: bool = False) -> None:
    """Reads a dataset chunk row by chunk row, naming the first unreadable or non-finite one
    (and with `quaternions`, the first rotation that is no unit quaternion)."""
    rows = ds.shape[0] if ds.ndim else 1
    step = max(1, (ds.chunks[0] if ds.chunks else 4096))
    for start in range(0, rows, step * 16):
        try:
            block = ds[start:start + step * 16] if ds.ndim else ds[()]
        except _STORAGE as exc:
            problems.append(f"{name}: rows from {start} unreadable ({exc})")
            return
        if block.dtype.kind == "f" and not np.isfinite(block).all():
            problems.append(f"{name}: non-finite values in rows from {start}")
            return
        bad = schema.non_unit_quaternion_problem(block, name, start=start) \
            if quaternions else None
        if bad is not None:
            problems.append(bad)
            return


def _check_skeletons(f: h5py.File, problems: list[str]) -> dict[str, tuple[int, int]]:
    """(joints, channels) per readable skeleton."""
    shapes = {}
    for key in f["skeletons"]:
        try:
            sk = schema.read_skeleton(f["skeletons"][key])
            shapes[key] = (sk.num_joints, sk.num_channels)
        except _STORAGE as exc:
            problems.append(f"/skeletons/{key}: unreadable ({exc})")
            continue
        problems += schema.skeleton_problems(sk, f"/skeletons/{key}")
    return shapes


def _check_take(g: h5py.Group, key: str, shapes: dict, full: bool, problems: list[str]) -> None:
    where = f"/takes/{key}"
    for attr in ("name", "skeleton", "frame_time"):
        if attr not in g.attrs:
            problems.append(f"{where}: attribute {attr!r} missing")
            return
    problem = schema.frame_time_problem(g.attrs["frame_time"])
    if problem is not None:  # (readers divide by it)
        problems.append(f"{where}: {problem}")
    sk = str(g.attrs["skeleton"])
    if sk not in shapes:
        problems.append(f"{where}: its skeleton {sk} is missing or unreadable")
        return
    joints, channels = shapes[sk]
    expected = {"channels": (channels,), "local_rotations": (joints, 4), "root_positions": (3,),
                "frame_indices": ()}
    frames = None
    for name in _TAKE_ARRAYS + (("received_at",) if "received_at" in g else ()):
        if name not in g:
            problems.append(f"{where}: dataset {name!r} missing")
            continue
        ds = g[name]
        frames = ds.shape[0] if frames is None else frames
        if ds.shape[0] != frames or ds.shape[1:] != expected.get(name, ()):
            problems.append(f"{where}/{name}: expected ({frames}, "
                            f"{', '.join(map(str, expected.get(name, ())))}) got {ds.shape}")
        elif full:
            _read_all(ds, f"{where}/{name}", problems, quaternions=name == "local_rotations")


def _check_poses(f: h5py.File, take_frames: dict[int, int], full: bool,
                 problems: list[str]) -> None:
    g = f["poses"]
    rotations = g["rotations"]
    if full:
        _read_all(rotations, "/poses/rotations", problems, quaternions=True)
    problems += pose_table_problems(PoseTable.read(g), take_frames, rotations.shape[0])


def pose_table_problems(table: PoseTable, take_frames: dict[int, int],
                        rotation_rows: int) -> list[str]:
    """What is wrong with a pose table (empty when nothing is): columns of unequal length,
    notes offsets that do not cover the notes, a pose of a take or frame that does not exist
    (`take_frames`: frames per take number), rotation rows outside the `rotation_rows` stored,
    supports with a bit that names no region (`schema.SUPPORT_BITS`), a root position or
    creation time that is not a number. Column by column, so that a table of 100,000 poses is
    checked in milliseconds."""
    n = len(table)
    cols = dict(table.cols, root_position=table.root, placement=table.placement)
    for key, col in cols.items():
        if len(col) != n:
            return [f"/poses/{key}: {len(col)} rows for {n} poses"]
    problems = []
    if len(table._notes_offsets) != n + 1 or table._notes_offsets[-1] != len(table._notes_blob):
        problems.append("/poses/notes_offsets: does not cover /poses/notes_utf8")
    take, frame = cols["take"], cols["frame"]
    start = cols["rotation_start"]
    end = start + cols["rotation_count"]
    ids = np.array(sorted(take_frames), dtype=np.int64)
    frames_of = np.array([take_frames[k] for k in ids.tolist()] + [0], dtype=np.int64)
    at = np.searchsorted(ids, take)  # (len(ids) for a take past the last: frames_of's 0)
    known = at < len(ids)
    known[known] = ids[at[known]] == take[known]
    in_take = known & (0 <= frame) & (frame < frames_of[at])
    supports = cols["supports"].astype(np.int64)
    stray = supports >> len(schema.SUPPORT_BITS)
    for row in np.flatnonzero(~known).tolist():
        problems.append(f"pose {table.names[row]!r} refers to take-{int(take[row]):05d}, which "
                        "does not exist")
    for row in np.flatnonzero(known & ~in_take).tolist():
        problems.append(f"pose {table.names[row]!r}: frame {int(frame[row])} of "
                        f"take-{int(take[row]):05d} does not exist")
    for row in np.flatnonzero(~((0 <= start) & (start <= end) & (end <= rotation_rows))).tolist():
        problems.append(f"pose {table.names[row]!r}: rotation rows {int(start[row])}.."
                        f"{int(end[row])} outside /poses/rotations ({rotation_rows} rows)")
    for row in np.flatnonzero(stray).tolist():
        problems.append(f"pose {table.names[row]!r}: supports {int(supports[row]):#06x} has "
                        f"bits above the {len(schema.SUPPORT_BITS)} that name body regions")
    for row in np.flatnonzero(~np.isfinite(table.root).all(axis=1)).tolist():
        problems.append(f"pose {table.names[row]!r}: root_position {table.root[row].tolist()} "
                        "is not a position in metres")
    finite = np.isfinite(table.placement)
    for row in np.flatnonzero(finite.any(axis=1) & ~finite.all(axis=1)).tolist():
        problems.append(f"pose {table.names[row]!r}: placement {table.placement[row].tolist()} "
                        "is neither an offset in metres and a heading nor all NaN")
    for row in np.flatnonzero(~np.isfinite(cols["created_at"])).tolist():
        problems.append(f"pose {table.names[row]!r}: created_at is "
                        f"{float(cols['created_at'][row])}, not a time")
    return problems


# attributes whose values the checks above judge by their meaning, not only as numbers
_JUDGED = {("takes", "frame_time"), ("skeletons", "unit_m")}


def _check_attributes(f: h5py.File, problems: list[str]) -> None:
    """Every number stored as an attribute is finite (a reader would print or use it)."""
    def visit(name: str, obj) -> None:
        for attr, value in obj.attrs.items():
            if (name.split("/")[0], attr) in _JUDGED and name.count("/") == 1:
                continue
            values = np.asarray(value)
            if values.dtype.kind in "fc" and not np.isfinite(values).all():
                problems.append(f"/{name}: attribute {attr!r} is {value}, not a number")

    visit("", f)
    f.visititems(visit)


def _check_counters(f: h5py.File, problems: list[str]) -> None:
    next_take = int(f.attrs.get("next_take_id", 1))
    for key in f["takes"]:
        if key.startswith("take-") and key[5:].isdigit() and int(key[5:]) >= next_take:
            problems.append(f"/takes/{key}: id not below next_take_id {next_take}")


def verify_file(f: h5py.File, path: Path, *, full: bool = True) -> list[str]:
    """What is wrong with an open library (empty when nothing is); see the module docstring."""
    try:
        schema.check(f, path)
    except schema.LibraryError as exc:
        return [str(exc)]
    problems: list[str] = []
    try:
        shapes = _check_skeletons(f, problems)
        take_frames = {}
        for key in f["takes"]:
            g = f["takes"][key]
            _check_take(g, key, shapes, full, problems)
            if key[5:].isdigit() and "channels" in g:
                take_frames[int(key[5:])] = g["channels"].shape[0]
        _check_poses(f, take_frames, full, problems)
        _check_counters(f, problems)
        _check_attributes(f, problems)
    except _STORAGE as exc:
        problems.append(f"unreadable structure ({exc})")
    return problems


def verify(path: str | Path, *, full: bool = True) -> list[str]:
    """What is wrong with the library at `path` (empty when nothing is)."""
    path = Path(path)
    try:
        with schema.open_checked(path) as f:
            return verify_file(f, path, full=full)
    except schema.StorageError as exc:
        return [str(exc)]
    except schema.SchemaError as exc:
        return [str(exc)]
