"""Checking a pose library before it is changed (`sitrelax db check`).

A quick check reads every object's metadata, every skeleton and the pose table, and checks
that they agree: each take's skeleton exists and its arrays have one row per frame and the
skeleton's widths, each pose's take and frame exist and its rotation rows lie inside
`/poses/rotations`, and the notes offsets cover the notes. A full check also reads every
chunk of every dataset, so a flipped bit in compressed data (which zlib's checksum catches)
is found, and checks that the arrays are finite.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np

from . import schema
from .posetable import PoseTable

_STORAGE = (OSError, KeyError, RuntimeError, ValueError, TypeError, UnicodeDecodeError)
_TAKE_ARRAYS = ("channels", "local_rotations", "root_positions", "frame_indices")


def _read_all(ds: h5py.Dataset, name: str, problems: list[str]) -> None:
    """Reads a dataset chunk row by chunk row, naming the first unreadable or non-finite one."""
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
        for name, values in (("offsets", sk.offsets), ("end_sites", sk.end_sites)):
            bad = ~np.isfinite(np.asarray(values, dtype=np.float64))
            if bad.any():  # (an export would write a BVH file no reader takes)
                problems.append(f"/skeletons/{key}/{name}: {int(bad.sum())} value(s) that are "
                                "not numbers")
    return shapes


def _check_take(g: h5py.Group, key: str, shapes: dict, full: bool, problems: list[str]) -> None:
    where = f"/takes/{key}"
    for attr in ("name", "skeleton", "frame_time"):
        if attr not in g.attrs:
            problems.append(f"{where}: attribute {attr!r} missing")
            return
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
            _read_all(ds, f"{where}/{name}", problems)


def _check_poses(f: h5py.File, take_frames: dict[int, int], full: bool,
                 problems: list[str]) -> None:
    g = f["poses"]
    rotations = g["rotations"]
    if full:
        _read_all(rotations, "/poses/rotations", problems)
    table = PoseTable.read(g)
    n = len(table)
    for key, col in table.cols.items():
        if len(col) != n:
            problems.append(f"/poses/{key}: {len(col)} rows for {n} poses")
            return
    if len(table._notes_offsets) != n + 1 or table._notes_offsets[-1] != len(table._notes_blob):
        problems.append("/poses/notes_offsets: does not cover /poses/notes_utf8")
    for row in range(n):
        take, frame = int(table.cols["take"][row]), int(table.cols["frame"][row])
        start = int(table.cols["rotation_start"][row])
        end = start + int(table.cols["rotation_count"][row])
        if take not in take_frames or not 0 <= frame < take_frames[take]:
            problems.append(f"pose {table.names[row]!r}: frame {frame} of take-{take:05d} "
                            "does not exist")
        if not 0 <= start <= end <= rotations.shape[0]:
            problems.append(f"pose {table.names[row]!r}: rotation rows {start}..{end} outside "
                            f"/poses/rotations ({rotations.shape[0]} rows)")


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
