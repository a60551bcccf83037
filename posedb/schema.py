"""The pose library's HDF5 layout, version 3.

    /                       attrs: sitrelax_kind = "pose-library", sitrelax_schema = 3,
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
                            local rotations (xyzw); placement (P, 4) float64: where a pose stands
                            relative to the standard placement (`PosePlacement`: offset x, y, z
                            in metres and heading in radians, in the pose's own frame), a row of
                            NaN for a pose placed the standard way (every pose but one stored by
                            `sitrelax relax --save`)
    /scenarios/<name>       attrs: scenario_json (the scenario's TOML data as JSON),
                            result_json (its summary row and per-person evaluation), source
                            (the file or template + pose it came from), created_at; written by
                            `sitrelax batch`
    /bodies                 reserved for body shapes

Versions. 1 stored `supports` as uint8 with bits 0-7 for head, torso, arms, hands, legs, feet,
thighs, calves (every bit in use). 2 widens the column to uint16 and adds the regions that split
the torso and the arms (bits 8-12: upper_back, lower_back, pelvis, upper_arms, forearms); every
bit keeps its meaning, so a version 1 mask reads unchanged in version 2: bit 1 (torso) is still
the upper back, lower back and pelvis together. Version 2 on writes region bits only (torso,
arms and legs as their regions); the coarse bits 1, 2 and 4 are only ever read. 3 adds the pose
table's `placement` column (all NaN for the poses of an older file: each placed the standard
way); a version 2 file is read without it, as if all NaN.

Every take is written through `take_arrays`, which checks each array against the type it is
stored as (finite, within float32's range for the rotations and root positions, whole for the
frame indices) and the frame time, before anything is written.

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
SCHEMA_VERSION = 3
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


class InvalidDataError(LibraryError):
    """Data a library write refuses: values that are not finite numbers, or that the type they
    are stored as cannot hold (float32 overflows to infinity beyond about 3.4e38)."""


# what h5py raises for damaged files: OSError (unreadable objects, failed filters), KeyError
# (missing links), RuntimeError (broken B-trees), ValueError and TypeError (garbled shapes,
# types or UTF-8), and zlib's own errors through OSError
_STORAGE_ERRORS = (OSError, KeyError, RuntimeError, ValueError, TypeError)


def damaged(path: Path, exc: BaseException) -> StorageError:
    """The one message of every storage error: the file, what failed, what to run."""
    what = str(exc).strip() or type(exc).__name__
    return StorageError(f"{path} is damaged and cannot be read ({what}); `sitrelax db check "
                        f"--db {path}` lists what is wrong")


def damaged_content(path: Path, problems: list[str], *,
                    refused_change: bool = False) -> StorageError:
    """The one message of a library whose content `posedb.verify` (or a reader) finds wrong:
    the file, the first problem and how many more, what to run (`refused_change`: and that a
    change to it was refused)."""
    more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
    state = "is damaged, so it was not changed" if refused_change else "is damaged"
    return StorageError(f"{path} {state}: {problems[0]}{more}; `sitrelax db check --db {path}` "
                        "lists what is wrong")


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


def skeleton_problems(sk: Skeleton, where: str) -> list[str]:
    """What makes a skeleton unfit to store or use (empty when nothing does): offsets and end
    sites that are not numbers (an export would write a BVH file no reader takes) and a length
    unit that is unknown or not a positive number of metres (the library stores only skeletons
    of a known unit: a take's lengths are read in metres). `where` names it in the messages."""
    problems = []
    for name, values in (("offsets", sk.offsets), ("end_sites", sk.end_sites)):
        bad = ~np.isfinite(np.asarray(values, dtype=np.float64))
        if bad.any():
            problems.append(f"{where}/{name}: {int(bad.sum())} value(s) that are not numbers")
    unit = sk.unit_m
    if unit is None or not (np.isfinite(unit) and unit > 0):
        shown = "unknown (nan)" if unit is None else unit
        problems.append(f"{where}: attribute 'unit_m' is {shown}, not a positive number of "
                        "metres per file unit")
    return problems


def frame_time_problem(frame_time) -> str | None:
    """Why a take's frame time cannot be stored or used, as "frame_time is ..." (None when it
    can): it must be a number of seconds in the range a BVH file may give
    (`capture.bvh.MIN_FRAME_TIME` to `MAX_FRAME_TIME`), so that durations, frame counts and an
    export are all well defined."""
    from capture.bvh import MAX_FRAME_TIME, MIN_FRAME_TIME

    try:
        seconds = float(frame_time)
    except (TypeError, ValueError):
        seconds = None
    if seconds is not None and MIN_FRAME_TIME <= seconds <= MAX_FRAME_TIME:  # (NaN fails)
        return None
    shown = frame_time if seconds is None else seconds
    return (f"frame_time is {shown!r}, not a number of seconds from {MIN_FRAME_TIME:g} to "
            f"{MAX_FRAME_TIME:g}")


UNIT_QUATERNION_TOLERANCE = 1e-3  # |norm - 1|: float32 xyzw written unit are within 1e-6


def non_unit_quaternion(rotations: np.ndarray) -> tuple[int, float] | None:
    """The first stored rotation that is no unit quaternion, as (row along the first axis, its
    norm), or None when each is one (NaN counts as none: it is reported as not a number).

    rotations : (..., 4) xyzw, as the library keeps them (a take's (T, J, 4), the poses'
    (R, 4)). A zero or scaled quaternion is damage: every writer stores unit ones, and a
    reader would refuse the zero one or silently normalise another.
    """
    values = np.asarray(rotations, dtype=np.float64)
    if values.size == 0:
        return None
    norm = np.linalg.norm(values, axis=-1)
    bad = np.abs(norm - 1.0) > UNIT_QUATERNION_TOLERANCE  # (NaN compares False)
    if not bad.any():
        return None
    at = np.unravel_index(int(np.argmax(bad)), bad.shape)
    return int(at[0]), float(norm[at])


def non_unit_quaternion_problem(rotations: np.ndarray, where: str, unit: str = "row",
                                start: int = 0) -> str | None:
    """`non_unit_quaternion` of `rotations` as a damage report naming `where` and the `unit`
    (row, frame) of the first, counted from `start`; None when every rotation is a unit one."""
    bad = non_unit_quaternion(rotations)
    if bad is None:
        return None
    return (f"{where}: {unit} {start + bad[0]} holds a rotation of norm {bad[1]:.6g}, not a "
            f"unit quaternion")


def _first(mask: np.ndarray, values: np.ndarray) -> tuple[int, object]:
    """The frame (first index) and the value of the first element where `mask` is true."""
    at = np.unravel_index(int(np.argmax(mask)), mask.shape)
    return (int(at[0]) if at else 0), values[at].item()


def stored_array(values, dtype, name: str, what: str, *, hint: str = "") -> np.ndarray:
    """`values` (frames along the first axis) as the library stores them, in `dtype`, after
    checking that they are numbers, finite and within the range of `dtype` (and whole for an
    integer dtype), so that the cast never overflows to infinity nor wraps. An
    InvalidDataError names `what` (the take), the dataset `name`, the first bad frame and
    value; `hint` ends the message."""
    values = np.asarray(values)
    target = np.dtype(dtype)
    hint = f" ({hint})" if hint else ""
    if values.dtype.kind not in "biuf":
        raise InvalidDataError(f"Expected numbers as {name} of {what}, got {values.dtype} "
                               f"values{hint}")
    if values.dtype.kind == "f":
        bad = ~np.isfinite(values)
        if bad.any():
            frame, value = _first(bad, values)
            raise InvalidDataError(f"Expected finite {name} for {what}, got {value} in frame "
                                   f"{frame}{hint}")
        if target.kind in "iu":
            bad = values != np.floor(values)
            if bad.any():
                frame, value = _first(bad, values)
                raise InvalidDataError(f"Expected whole numbers as {name} of {what}, got "
                                       f"{value} in frame {frame}{hint}")
    info = np.finfo(target) if target.kind == "f" else np.iinfo(target)
    if values.size and values.dtype != target:
        if values.dtype.kind == "f":  # (as a float, an integer type's maximum rounds up)
            wide = values.astype(np.float64)
            bad = (wide < float(info.min)) | (wide > float(info.max)) if target.kind == "f" \
                else (wide < float(info.min)) | (wide >= float(info.max) + 1)
        else:
            bad = (values < info.min) | (values > info.max)
        if bad.any():
            frame, value = _first(bad, values)
            raise InvalidDataError(
                f"Expected {name} of {what} within {float(info.min):.4g}..{float(info.max):.4g} "
                f"(stored as {target.name}), got {value:.4g} in frame {frame}{hint}")
    return values.astype(target)


def take_arrays(skeleton: Skeleton, channels, frame_time, what: str, *,
                frame_indices=None, received_at=None) -> dict[str, np.ndarray]:
    """The datasets of a take as they are stored (see the module docstring), each checked
    before anything is written: the one check every writer of takes goes through (an import,
    a live recording, the recovery of a journal). Raises a LibraryError naming `what` (the
    take, and its file) and the problem: no frame, a wrong shape, values that are not finite or
    that their stored type cannot hold, a frame time out of range, a skeleton unfit to store.

    channels : (T, C) raw channels of `skeleton` (stored float32 when given so, else float64).
    frame_time : seconds between frames.
    frame_indices : (T,) whole numbers (default 0..T-1); received_at : (T,) Unix seconds.
    """
    channels = np.asarray(channels)
    c = skeleton.num_channels
    if channels.ndim == 2 and channels.shape[1] == c and not len(channels):
        raise LibraryError(f"Expected at least one frame for {what}, got none (a header-only "
                           "file, `Frames: 0`, holds no motion to store)")
    if channels.ndim != 2 or channels.shape[1] != c:
        raise LibraryError(f"Expected channels (T > 0, {c}) for {what}, got {channels.shape}")
    problems = [p for p in (frame_time_problem(frame_time),) if p]
    problems += skeleton_problems(skeleton, "skeleton")
    if problems:
        raise InvalidDataError(f"Expected a take fit to store for {what}, got {problems[0]}")
    t = channels.shape[0]
    kind = np.float32 if channels.dtype == np.float32 else np.float64
    out = {"channels": stored_array(channels, kind, "channels", what)}
    with np.errstate(all="ignore"):  # (an overflow is found below, not warned about)
        rotations = skeleton.local_rotations(out["channels"])
        roots = skeleton.root_positions(out["channels"])
    out["local_rotations"] = stored_array(rotations, np.float32, "local rotations", what)
    out["root_positions"] = stored_array(
        roots, np.float32, "root positions (m)", what,
        hint="check the file's numbers and its length unit")
    for name, values in (("frame_indices", np.arange(t) if frame_indices is None
                          else frame_indices), ("received_at", received_at)):
        if values is None:
            continue
        values = np.asarray(values)
        if values.shape != (t,):
            raise LibraryError(f"Expected {name} ({t},) for {what}, got {values.shape}")
        out[name] = stored_array(values, np.int64 if name == "frame_indices" else np.float64,
                                 name, what)
    return out


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


def _add_placement(f: h5py.File) -> None:
    """Version 2 -> 3: the pose table's `placement` column, NaN (the standard placement) for
    every pose."""
    poses = f["poses"]
    if "id" in poses and "placement" not in poses:
        poses.create_dataset("placement", data=np.full((poses["id"].shape[0], 4), np.nan))


MIGRATIONS: dict[int, Callable[[h5py.File], None]] = {1: _widen_supports, 2: _add_placement}


def upgrade(f: h5py.File) -> int:
    """Brings a library open for writing up to SCHEMA_VERSION, one MIGRATIONS step at a time
    (`check` has refused a file no step leads from); returns the version it had."""
    before = version = int(f.attrs[VERSION_ATTR])
    while version < SCHEMA_VERSION:
        MIGRATIONS[version](f)
        version += 1
        f.attrs[VERSION_ATTR] = version
    return before
