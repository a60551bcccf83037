"""The pose library's HDF5 layout, version 2.

    /                       attrs: sitrelax_kind = "pose-library", sitrelax_schema = 2,
                                   created_at, next_take_id, next_pose_id
    /skeletons/<skel-hash>  datasets: names (J,) str, parents (J,) int32, offsets (J, 3) float64
                            (file units), channels (J,) str (space-separated channel names per
                            joint), end_sites (E, 3) float64, end_site_parents (E,) int32;
                            attrs: unit_m (metres per file unit), profile
    /takes/<take-NNNNN>     attrs: name, skeleton, frame_time, source, subject, recorded_at,
                            tags (space-separated), notes, origin ("bvh", "stream", or
                            "relaxed": a pose relaxed onto a surface, in the body rig's
                            skeleton, whose source is the pose id or BVH reference it came
                            from);
                            datasets, chunked along frames and gzip-compressed:
                            channels (T, C) raw channels (float64 from BVH text, float32 as
                            streamed), local_rotations (T, J, 4) float32 xyzw, root_positions
                            (T, 3) float32 metres, frame_indices (T,) int64, and for streamed
                            takes received_at (T,) float64 Unix seconds
    /poses                  the pose table, one column per dataset (see `posedb.posetable`):
                            id, take, frame (0-based in the take), rotation_start,
                            rotation_count int64; supports uint16 (bit k: SUPPORT_BITS[k], the
                            body regions to support); created_at float64; root_position (P, 3)
                            float64 metres; names_utf8 (names joined by line breaks);
                            notes_utf8 + notes_offsets; tag_vocabulary (K,) str + tag_matrix
                            (P, K) uint8; rotations (R, 4) float32: each pose's own copy of its
                            local rotations (xyzw)
    /scenarios/<name>       attrs: scenario_json (the scenario's TOML data as JSON),
                            result_json (its summary row and per-person evaluation), source
                            (the file or template + pose it came from), created_at; written by
                            `sitrelax batch`
    /bodies                 reserved for body shapes

Versions. 1 stored `supports` as uint8 with bits 0-7 for head, torso, arms, hands, legs, feet,
thighs, calves (every bit in use). 2 widens the column to uint16 and adds the regions that split
the torso and the arms (bits 8-12: upper_back, lower_back, pelvis, upper_arms, forearms); every
bit keeps its meaning, so a version 1 mask reads unchanged in version 2: bit 1 (torso) is still
the upper back, lower back and pelvis together. Version 2 writes region bits only (torso, arms
and legs as their regions); the coarse bits 1, 2 and 4 are only ever read.

A file of a newer schema is refused; an older one is read as it is and, before its first change,
brought up to this version by the functions in `MIGRATIONS` (`upgrade`), step by step.
"""

from __future__ import annotations

import json
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterable, Iterator

import h5py
import numpy as np

from capture import Skeleton

from .regions import BODY_REGIONS, SUPPORT_GROUPS, SupportNameError, support_regions

KIND_ATTR = "sitrelax_kind"
KIND = "pose-library"
VERSION_ATTR = "sitrelax_schema"
SCHEMA_VERSION = 2
# bit k of a pose's `supports` names SUPPORT_BITS[k]: a region, or (bits 1, 2, 4, read from
# version 1 files only) a coarse part, the union of its regions
SUPPORT_BITS = ("head", "torso", "arms", "hands", "legs", "feet", "thighs", "calves",
                "upper_back", "lower_back", "pelvis", "upper_arms", "forearms")

_STR = h5py.string_dtype()


class LibraryError(ValueError):
    """A pose library that cannot be used as asked."""


class NotFoundError(LibraryError):
    """No such library, take or pose."""


class SchemaError(LibraryError):
    """A file that is not a pose library of a schema this version can read."""


class StorageError(LibraryError):
    """A library whose bytes cannot be read back as written (damaged, truncated)."""


# what h5py raises for damaged files: OSError (unreadable objects, failed filters), KeyError
# (missing links), RuntimeError (broken B-trees), ValueError and TypeError (garbled shapes,
# types or UTF-8), and zlib's own errors through OSError
_STORAGE_ERRORS = (OSError, KeyError, RuntimeError, ValueError, TypeError)


def damaged(path: Path, exc: BaseException) -> StorageError:
    """The one message of every storage error: the file, what failed, what to run."""
    what = str(exc).strip() or type(exc).__name__
    return StorageError(f"{path} is damaged and cannot be read ({what}); `sitrelax db check "
                        f"--db {path}` lists what is wrong")


@contextmanager
def storage_errors(path: Path) -> Iterator[None]:
    """Turns the HDF5 library's errors inside the block into a StorageError naming `path`."""
    try:
        yield
    except LibraryError:
        raise
    except _STORAGE_ERRORS as exc:
        raise damaged(path, exc) from exc


def initialise(f: h5py.File) -> None:
    """Lays out an empty library in a new file."""
    f.attrs[KIND_ATTR] = KIND
    f.attrs[VERSION_ATTR] = SCHEMA_VERSION
    f.attrs["created_at"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    f.attrs["next_take_id"] = 1
    f.attrs["next_pose_id"] = 1
    for name in ("skeletons", "takes", "bodies", "scenarios"):
        f.create_group(name)
    poses = f.create_group("poses")
    poses.create_dataset("rotations", shape=(0, 4), maxshape=(None, 4), dtype=np.float32,
                         chunks=(4096, 4), compression="gzip", compression_opts=4)


def check(f: h5py.File, path: Path) -> None:
    kind = f.attrs.get(KIND_ATTR)
    if isinstance(kind, bytes):
        kind = kind.decode()
    if kind != KIND:
        raise SchemaError(f"{path} is an HDF5 file but not a sitrelax pose library")
    version = f.attrs.get(VERSION_ATTR)
    try:
        version = int(version)
    except (TypeError, ValueError):
        raise SchemaError(f"{path} has an unreadable schema version {version!r}") from None
    if version > SCHEMA_VERSION:
        raise SchemaError(
            f"{path} has schema version {version}, newer than this sitrelax reads "
            f"({SCHEMA_VERSION}): upgrade sitrelax"
        )
    if version < SCHEMA_VERSION and version not in MIGRATIONS:
        raise SchemaError(
            f"{path} has schema version {version}, which this sitrelax cannot migrate to "
            f"{SCHEMA_VERSION}"
        )
    for name in ("skeletons", "takes", "poses"):
        if name not in f:
            raise SchemaError(f"{path} is a damaged pose library: its /{name} group is missing")


@contextmanager
def open_checked(path: Path) -> Iterator[h5py.File]:
    """Opens a library read-only after checking it is one, of a schema this version reads."""
    path = Path(path)
    if not path.exists():
        raise NotFoundError(f"No pose library at {path}")
    if path.is_dir():
        raise LibraryError(f"{path} is a directory, not a pose library")
    if not h5py.is_hdf5(path):
        raise SchemaError(f"{path} is not an HDF5 file, so not a pose library")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise SchemaError(f"{path} is damaged or truncated and cannot be opened ({exc})") from None
    try:
        with storage_errors(path):
            check(f, path)
            yield f
    finally:
        f.close()


def write_skeleton(g: h5py.Group, sk: Skeleton) -> None:
    from capture import identify_profile

    g.create_dataset("names", data=np.array(sk.names, dtype=object), dtype=_STR)
    g.create_dataset("parents", data=sk.parents.astype(np.int32))
    g.create_dataset("offsets", data=sk.offsets)
    g.create_dataset("channels", data=np.array([" ".join(c) for c in sk.channels], dtype=object),
                     dtype=_STR)
    g.create_dataset("end_sites", data=sk.end_sites.reshape(-1, 3))
    g.create_dataset("end_site_parents", data=sk.end_site_parents.astype(np.int32))
    g.attrs["unit_m"] = np.nan if sk.unit_m is None else float(sk.unit_m)
    g.attrs["profile"] = identify_profile(sk.names) or ""
    if sk.joint_map:
        g.attrs["joint_map"] = json.dumps(dict(sk.joint_map), sort_keys=True)


def read_skeleton(g: h5py.Group) -> Skeleton:
    unit = float(g.attrs["unit_m"])
    return Skeleton(
        names=tuple(s.decode("utf-8") for s in g["names"][:]),
        parents=g["parents"][:],
        offsets=g["offsets"][:],
        channels=tuple(tuple(s.decode("utf-8").split()) for s in g["channels"][:]),
        end_sites=g["end_sites"][:],
        end_site_parents=g["end_site_parents"][:],
        unit_m=None if np.isnan(unit) else unit,
        joint_map=tuple(json.loads(g.attrs.get("joint_map", "{}")).items()),
    )


def encode_supports(names: Iterable[str] | str) -> int:
    """The bit mask (SUPPORT_BITS) of the body regions that `names` cover: regions, coarse parts
    or uses (`posedb.regions.support_regions`); a LibraryError names an unknown one."""
    try:
        regions = support_regions(names)
    except SupportNameError as exc:
        raise LibraryError(str(exc)) from None
    mask = 0
    for region in regions:
        mask |= 1 << SUPPORT_BITS.index(region)
    return mask


def decode_supports(mask: int) -> tuple[str, ...]:
    """The body regions (in BODY_REGIONS order) of a `supports` bit mask of any version."""
    named = [name for k, name in enumerate(SUPPORT_BITS) if mask >> k & 1]
    regions = {r for name in named for r in SUPPORT_GROUPS.get(name, (name,))}
    return tuple(r for r in BODY_REGIONS if r in regions)


def _widen_supports(f: h5py.File) -> None:
    """Version 1 -> 2: the pose table rewritten with `supports` as uint16 (values unchanged)."""
    from .posetable import PoseTable  # it needs this module's errors (through posedb.tags)

    poses = f["poses"]
    if "supports" in poses:
        PoseTable.read(poses).write(poses)


MIGRATIONS: dict[int, Callable[[h5py.File], None]] = {1: _widen_supports}


def upgrade(f: h5py.File) -> int:
    """Brings a library open for writing up to SCHEMA_VERSION, one MIGRATIONS step at a time
    (`check` has refused a file no step leads from); returns the version it had."""
    before = version = int(f.attrs[VERSION_ATTR])
    while version < SCHEMA_VERSION:
        MIGRATIONS[version](f)
        version += 1
        f.attrs[VERSION_ATTR] = version
    return before
