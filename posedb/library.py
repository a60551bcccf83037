"""The pose library: one HDF5 file of skeletons, takes and poses (schema in `posedb.schema`).

Reading opens the file read-only and returns numpy arrays and plain records, never live HDF5
handles. Writing is copy-on-write: every change (or batch of changes in `edit()`) is made on a
copy of the file, which replaces the original in one rename only when the whole change has
succeeded. A failed or killed writer therefore leaves the library exactly as it was, and readers
never see half a change. Writers take a lock (`posedb.locking`) so they queue instead of
losing each other's changes; they hold it only to copy, change and rename (a BVH file is parsed
before), and wait for a long writer (reporting the wait) up to `lock_timeout` seconds.

The copy keeps the file's mode, owner and symbolic link (`posedb.files`); a file without write
permission is refused. Before a change the library is verified (`posedb.verify`: fully for a
file up to 64 MB, its structure for a larger one), so damage is reported rather than carried
into the new copy; every error of the storage layer names the file. Readers refuse damage too:
opening checks the values of the index it reads (each take's frame time; each pose's take,
frame, supports and root position), and reading a take or pose checks its skeleton and arrays,
so a value that is not a number is reported (`db check` lists all) rather than divided by or
printed.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import time
import unicodedata
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterable, Iterator

import h5py
import numpy as np

from capture import Bvh, Motion, Skeleton, identify_profile, read_bvh

from . import files, schema
from .compact import compact_into
from .locking import LockedError, exclusive, lock_wait, try_exclusive
from .posetable import PoseTable
from .regions import DEFAULT_SUPPORT
from .schema import LibraryError, NotFoundError, decode_supports, encode_supports
from .tags import compile_expression, membership, normalise_tags
from .verify import pose_table_problems, verify, verify_file

# seconds a writer waits for another one before giving up ($SITRELAX_LOCK_TIMEOUT overrides)
DEFAULT_LOCK_TIMEOUT = 600.0
FULL_CHECK_BYTES = 64 << 20  # libraries up to this size are read entirely before each change


def default_lock_timeout() -> float | None:
    """$SITRELAX_LOCK_TIMEOUT in seconds ("none", a negative or an infinite number: wait as long
    as the writer lives)."""
    text = os.environ.get("SITRELAX_LOCK_TIMEOUT", "").strip().lower()
    if not text:
        return DEFAULT_LOCK_TIMEOUT
    if text in ("none", "forever"):
        return None
    try:
        seconds = float(text)
    except ValueError:
        raise LibraryError(f"Expected $SITRELAX_LOCK_TIMEOUT in seconds or 'none', got "
                           f"{text!r}") from None
    return lock_wait(seconds, "$SITRELAX_LOCK_TIMEOUT")


class DuplicateNameError(LibraryError):
    """A name already used by another take or pose."""


@dataclass(frozen=True)
class TakeInfo:
    """A take's metadata (its arrays come from `PoseLibrary.take_data`)."""

    id: str
    name: str
    skeleton: str
    frames: int
    frame_time: float
    source: str
    subject: str
    recorded_at: str
    tags: tuple[str, ...]
    notes: str
    kind: str  # "bvh" or "stream"

    @property
    def duration(self) -> float:
        return self.frames * self.frame_time

    def as_dict(self) -> dict:
        return {"id": self.id, "kind": "take", "name": self.name, "tags": list(self.tags),
                "skeleton": self.skeleton, "frames": self.frames, "frame_time": self.frame_time,
                "duration": self.duration, "source": self.source, "subject": self.subject,
                "recorded_at": self.recorded_at, "notes": self.notes, "origin": self.kind}


@dataclass(frozen=True)
class PosePlacement:
    """Where a pose stands relative to the standard placement (its lowest skin point on the
    floor, its pelvis over the origin), in the pose's own frame: the frame its rotations and
    root position are stored in, Y up, before a scenario turns and moves it. A pose stored by
    `sitrelax relax --save` carries one, so that placed again it stands where the relaxation
    left it (`solver.scene.placement.place_person`).

    offset : (3,) metres added to the standard placement (y: the lowest skin point's height).
    heading : radians about +Y, the turn to face +Z that a scenario's ``facing = "front"``
        applies (that of the pose it was relaxed from, not measured on this one).
    """

    offset: tuple[float, float, float]
    heading: float

    def __post_init__(self) -> None:
        try:
            values = np.asarray([*self.offset, self.heading], dtype=np.float64)
        except (TypeError, ValueError):
            values = None
        if values is None or values.shape != (4,) or not np.isfinite(values).all():
            raise schema.InvalidDataError(f"Expected a placement as an offset (x, y, z) in "
                                          f"metres and a heading in radians, all finite, got "
                                          f"{tuple(self.offset)!r} and {self.heading!r}")
        object.__setattr__(self, "offset", tuple(float(x) for x in self.offset))
        object.__setattr__(self, "heading", float(self.heading))

    def as_dict(self) -> dict:
        return {"offset_m": list(self.offset), "heading_rad": self.heading}


@dataclass(frozen=True)
class PoseInfo:
    """A pose: a named frame of a take, with tags, the body regions it needs supported (in
    `posedb.regions.BODY_REGIONS` order), notes and, for a relaxed pose, where it stands
    (`PosePlacement`; None: the standard placement)."""

    id: str
    name: str
    take: str  # take id
    frame: int
    tags: tuple[str, ...]
    supports: tuple[str, ...]
    notes: str
    created_at: float
    placement: PosePlacement | None = None

    def as_dict(self, take_name: str | None = None) -> dict:
        return {"id": self.id, "kind": "pose", "name": self.name, "tags": list(self.tags),
                "take": take_name if take_name is not None else self.take,
                "take_id": self.take, "frame": self.frame, "supports": list(self.supports),
                "notes": self.notes, "created_at": self.created_at,
                "placement": None if self.placement is None else self.placement.as_dict()}


@dataclass(frozen=True, eq=False)
class TakeData:
    """A take's arrays.

    channels : (T, C) raw channels as stored (float64 for BVH imports, float32 as streamed).
    local_rotations : (T, J, 4) float32 quaternions (x, y, z, w).
    root_positions : (T, 3) float32 metres.
    frame_indices : (T,) int64 (the sender's indices for a stream, else 0..T-1 of the source).
    received_at : (T,) float64 Unix times for a streamed take, else None.
    """

    take: TakeInfo
    skeleton: Skeleton
    channels: np.ndarray
    local_rotations: np.ndarray
    root_positions: np.ndarray
    frame_indices: np.ndarray
    received_at: np.ndarray | None
    start: int = 0

    def motion(self) -> Motion:
        return Motion(np.asarray(self.channels, dtype=np.float64), self.take.frame_time)


def _take_id(n: int) -> str:
    return f"take-{n:05d}"


def _pose_id(n: int) -> str:
    return f"pose-{n:06d}"


def _parse_id(text: str, prefix: str) -> int | None:
    if text.startswith(prefix) and text[len(prefix):].isdigit():
        return int(text[len(prefix):])
    return None


def _whole(value, name: str) -> int:
    """A frame number as an int; a LibraryError for anything but a whole number (5.7 is no
    frame, and would be cut to 5 silently)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        if not (isinstance(value, (float, np.floating)) and float(value).is_integer()):
            raise LibraryError(f"Expected a whole frame number for {name}, got {value!r}")
    return int(value)


def _find_take(takes: dict[str, TakeInfo], ref: str, path: Path) -> TakeInfo:
    """A take by id or name."""
    if ref in takes:
        return takes[ref]
    for t in takes.values():
        if t.name == ref:
            return t
    composed = unicodedata.normalize("NFC", ref)  # (names are stored composed: `checked_name`)
    if composed != ref:
        for t in takes.values():
            if t.name == composed:
                return t
    raise NotFoundError(f"No take {ref!r} in {path}")


def _find_pose(table: PoseTable, ref: str, path: Path) -> int:
    """The table row of a pose given by id or name."""
    row = table.row_of(ref)
    if row is None:
        raise NotFoundError(f"No pose {ref!r} in {path}")
    return row


UTC_STAMP = "%Y-%m-%dT%H:%M:%SZ"  # how a take's recorded_at is stored, whatever its source


def _utc_stamp(text: str) -> str:
    """An ISO 8601 time as UTC_STAMP (a streamed take's start, `...+00:00` with microseconds,
    as an imported take's); text that is not one is kept as given."""
    import datetime as dt

    try:
        moment = dt.datetime.fromisoformat(str(text))
    except ValueError:
        return str(text)
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=dt.timezone.utc)
    return moment.astimezone(dt.timezone.utc).strftime(UTC_STAMP)


_ID_FORM = re.compile(r"take-\d{5,}|pose-\d{6,}")  # the ids' own, zero-padded forms
MAX_NAME_LENGTH = 200  # characters of a take's or a pose's name (`checked_name`)


def name_holder(takes: dict[str, TakeInfo], table: PoseTable, name: str) -> str | None:
    """What holds `name` already ("take named 'x'", "pose named 'x'"), or None when it is free
    for a take or a pose: takes and poses share one namespace with their ids (a name of an
    id's form, `take-00002` or `pose-000007`, is refused by `checked_name`)."""
    if any(t.name == name for t in takes.values()):
        return f"take named {name!r}"
    if table.row_of(name) is not None:
        return f"pose named {name!r}"
    return None


def checked_text(text, what: str) -> str:
    """`text` (a name, notes, a subject, a source) as a str the library can store: a
    LibraryError for text with a NUL character (HDF5 strings end at one) or that is not valid
    Unicode (a lone surrogate: bytes that are not UTF-8, as a command line passes them on),
    which would otherwise fail the commit with a message calling the library damaged."""
    text = str(text)
    if "\x00" in text:
        raise LibraryError(f"Expected {what} without NUL characters, got {text[:60]!r}")
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        raise LibraryError(f"Expected {what} as UTF-8 text, got {text[:60]!r} (bytes that are "
                           "not UTF-8: check the terminal's or the file's encoding)") from None
    return text


def checked_name(name: str, kind: str = "pose") -> str:
    """A take's or pose's name as stored (stripped, composed: Unicode NFC); raises
    LibraryError for an empty one, one with '/', tabs, line breaks or other control
    characters, one that is not UTF-8 text (`checked_text`), or one over 200 characters."""
    name = str(name).strip()
    if not name:
        raise LibraryError(f"Expected a {kind} name, got an empty one")
    if "/" in name or any(unicodedata.category(c) == "Cc" for c in name):
        raise LibraryError(f"Expected a {kind} name without '/', tabs, line breaks or other "
                           f"control characters, got {name!r}")
    # composed (NFC), so that "café" typed and "café" from a decomposing file system (macOS)
    # are one name, not two that look alike and a reference tells apart by invisible bytes
    name = unicodedata.normalize("NFC", checked_text(name, f"a {kind} name"))
    if len(name) > MAX_NAME_LENGTH:
        raise LibraryError(f"Expected a {kind} name of at most {MAX_NAME_LENGTH} characters, "
                           f"got {len(name)}")
    if _ID_FORM.fullmatch(name):
        raise LibraryError(f"Expected a {kind} name that is not of an id's form (take-00002, "
                           f"pose-000007: a reference to it would name the id), got {name!r}")
    return name


def derived_name(base: str, suffix: str) -> str:
    """A name made from another by a suffix (`NAME-2` for a name taken, `TAKE-f00039` for a
    pose of a take): `base` shortened as far as needed for the whole to stay within
    `MAX_NAME_LENGTH` characters, the suffix kept whole, since it is what tells the names
    made from one base apart (a base of the limit's length is a valid name, and the name made
    from it must be one too), never between a letter and the marks that follow it (a letter
    cut from its accent would be another letter). Whether the name is free is the caller's
    to check."""
    cut = end = max(MAX_NAME_LENGTH - len(suffix), 0)
    while 0 < end < len(base) and unicodedata.category(base[end]).startswith("M"):
        end -= 1  # (a mark, spacing or not, belongs to the letter before it)
    return base[:end or cut].rstrip() + suffix


def skeleton_key(sk: Skeleton) -> str:
    """A content hash naming a distinct skeleton (names, hierarchy, offsets, channels, unit)."""
    h = hashlib.sha1()
    h.update(json.dumps([sk.names, sk.channels, sk.unit_m]).encode())
    if sk.joint_map:  # the same joints with roles given are a different skeleton to pose
        h.update(json.dumps(sk.joint_map).encode())
    for arr in (sk.parents, np.round(sk.offsets, 9), np.round(sk.end_sites, 9),
                sk.end_site_parents):
        h.update(np.ascontiguousarray(arr).tobytes())
    return "skel-" + h.hexdigest()[:12]


class PoseLibrary:
    """A pose library file. `PoseLibrary(path)` opens an existing one; `create=True` makes one.

    The index of takes and poses is read once on open and refreshed after each edit. A writer
    waits up to `lock_timeout` seconds for another (None: as long as that one lives; default
    `default_lock_timeout()`), calling `on_wait(seconds waited)` about once a second. Opening
    removes the copies killed writers left, when no writer is at work; `notes` says what went.
    """

    def __init__(self, path: str | os.PathLike, *, create: bool = False,
                 lock_timeout: float | None | str = "default", on_wait=None):
        self.path = Path(path)
        self.lock_timeout = default_lock_timeout() if lock_timeout == "default" else lock_timeout
        self.on_wait = on_wait
        self.notes: list[str] = []
        if not self.path.exists():
            if not create:
                raise NotFoundError(f"No pose library at {self.path} (import a take to make one)")
            with self._writer_lock():
                if not self.path.exists():
                    self._create()
        self._clean_up_if_idle()
        self._load()

    @property
    def target(self) -> Path:
        """The real file (a symbolic link's target), which changes are written to."""
        return files.real_file(self.path)

    # -- opening ------------------------------------------------------------------------------

    def _create(self) -> None:
        with files.replacing(self.target) as tmp:
            with h5py.File(tmp, "w") as f:
                schema.initialise(f)

    def _clean_up_if_idle(self) -> None:
        """Removes killed writers' copies when the lock is free now (never waits for it)."""
        if not files.stale_temporaries(self.target):
            return
        lock = try_exclusive(self.target)
        if lock is not None:
            try:
                self.notes += files.remove_stale_temporaries(self.target)
            finally:
                lock.release()

    def _load(self) -> None:
        with schema.open_checked(self.path) as f:
            self.schema_version = int(f.attrs[schema.VERSION_ATTR])
            self._next_take = int(f.attrs.get("next_take_id", 1))
            self._next_pose = int(f.attrs.get("next_pose_id", 1))
            self._takes = {}
            for key in sorted(f["takes"]):
                g = f["takes"][key]
                a = g.attrs
                self._takes[key] = TakeInfo(
                    id=key, name=str(a["name"]), skeleton=str(a["skeleton"]),
                    frames=int(g["channels"].shape[0]), frame_time=float(a["frame_time"]),
                    source=str(a.get("source", "")), subject=str(a.get("subject", "")),
                    recorded_at=str(a.get("recorded_at", "")),
                    tags=tuple(str(a.get("tags", "")).split()), notes=str(a.get("notes", "")),
                    kind=str(a.get("origin", "bvh")),
                )
            self._table = PoseTable.read(f["poses"])
            # the index is checked as read: a value no reader can use (a frame time of 0 or
            # NaN, a pose of a missing take) is reported here rather than divided by or printed
            problems = [f"/takes/{t.id}: {p}" for t in self._takes.values()
                        if (p := schema.frame_time_problem(t.frame_time))]
            frames = {_parse_id(k, "take-"): t.frames for k, t in self._takes.items()
                      if _parse_id(k, "take-") is not None}
            problems += pose_table_problems(self._table, frames, f["poses"]["rotations"].shape[0])
            if problems:
                raise schema.damaged_content(self.path, problems)

    @contextmanager
    def _writer_lock(self) -> Iterator[None]:
        """The write lock, then the removal of copies earlier writers left (with a note)."""
        target = self.target
        with exclusive(target, timeout=self.lock_timeout, on_wait=self.on_wait):
            self.notes += files.remove_stale_temporaries(target)
            yield

    def make_again_if_removed(self) -> bool:
        """Waits for the writer at work (as a change does), then makes the library again,
        empty, if it was removed meanwhile (a failed import removes the empty library it made:
        `posedb.cli`); whether it did."""
        with self._writer_lock():
            if self.path.exists():
                return False
            self._create()
        self._load()
        return True

    # -- reading ------------------------------------------------------------------------------

    def takes(self) -> list[TakeInfo]:
        return list(self._takes.values())

    def take(self, ref: str) -> TakeInfo:
        """A take by id or name."""
        return _find_take(self._takes, ref, self.path)

    def name_holder(self, name: str) -> str | None:
        """What holds `name` already, or None when it is free for a new take or pose (see the
        module's `name_holder`)."""
        return name_holder(self._takes, self._table, name)

    def skeleton(self, key: str) -> Skeleton:
        with schema.open_checked(self.path) as f:
            return self._read_skeleton(f, key)

    def _read_skeleton(self, f: h5py.File, key: str) -> Skeleton:
        """A stored skeleton, refused (as damage) when its offsets are not numbers or its unit
        is unknown: an export would write them, a take's metres could not be had."""
        sk = schema.read_skeleton(f["skeletons"][key])
        problems = schema.skeleton_problems(sk, f"/skeletons/{key}")
        if problems:
            raise schema.damaged_content(self.path, problems)
        return sk

    def _finite(self, arrays: dict[str, np.ndarray | None], where: str, start: int) -> None:
        """Refuses (as damage) arrays read from the library holding values that are not
        numbers; frames along the first axis, counted from `start`."""
        problems = []
        for name, values in arrays.items():
            if values is not None and values.dtype.kind == "f":
                bad = ~np.isfinite(values.reshape(len(values), -1)).all(axis=1)
                if bad.any():
                    problems.append(f"{where}/{name}: values that are not numbers in frame "
                                    f"{start + int(np.argmax(bad))}")
        rotations = arrays.get("local_rotations")
        bad = None if rotations is None else schema.non_unit_quaternion_problem(
            rotations, f"{where}/local_rotations", "frame", start)
        if bad is not None:
            problems.append(bad)
        if problems:
            raise schema.damaged_content(self.path, problems)

    def take_data(self, ref: str, start: int = 0, stop: int | None = None) -> TakeData:
        """A take's arrays for frames [start, stop) (0-based)."""
        info = self.take(ref)
        start = _whole(start, "start")
        stop = info.frames if stop is None else _whole(stop, "stop")
        if not (0 <= start < stop <= info.frames):
            empty = " (empty: a range holds at least one frame)" if stop <= start else ""
            raise ValueError(
                f"Expected a frame range within 0..{info.frames} of take {info.name!r}, got "
                f"{start}..{stop}{empty}"
            )
        with schema.open_checked(self.path) as f:
            g = f["takes"][info.id]
            sk = self._read_skeleton(f, info.skeleton)
            data = TakeData(
                info, sk, g["channels"][start:stop], g["local_rotations"][start:stop],
                g["root_positions"][start:stop], g["frame_indices"][start:stop],
                g["received_at"][start:stop] if "received_at" in g else None, start,
            )
        self._finite({"channels": data.channels, "local_rotations": data.local_rotations,
                      "root_positions": data.root_positions, "received_at": data.received_at},
                     f"/takes/{info.id}", start)
        return data

    def take_bvh(self, ref: str, start: int = 0, stop: int | None = None) -> Bvh:
        data = self.take_data(ref, start, stop)
        return Bvh(data.skeleton, data.motion(), identify_profile(data.skeleton.names))

    def _pose_info(self, row: int) -> PoseInfo:
        t = self._table
        placed = t.placement_of(row)
        return PoseInfo(_pose_id(t.value("id", row)), t.names[row],
                        _take_id(t.value("take", row)), t.value("frame", row), t.tags(row),
                        decode_supports(t.value("supports", row)), t.notes(row),
                        t.value("created_at", row),
                        PosePlacement(tuple(placed[:3]), placed[3])
                        if np.isfinite(placed).all() else None)

    def _pose_row(self, ref: str) -> int:
        return _find_pose(self._table, ref, self.path)

    def pose(self, ref: str) -> PoseInfo:
        """A pose by id or name."""
        return self._pose_info(self._pose_row(ref))

    def pose_data(self, ref: str) -> tuple[PoseInfo, Skeleton, np.ndarray, np.ndarray]:
        """A pose with its skeleton, local rotations (J, 4) xyzw and root position (3,) m."""
        row = self._pose_row(ref)
        info = self._pose_info(row)
        t = self._table
        start, count = t.value("rotation_start", row), t.value("rotation_count", row)
        with schema.open_checked(self.path) as f:
            rot = f["poses"]["rotations"][start:start + count]
            sk = self._read_skeleton(f, self.take(info.take).skeleton)
        if not np.isfinite(rot).all():
            raise schema.damaged_content(self.path, [
                f"pose {info.name!r}: /poses/rotations rows {start}..{start + count} hold "
                "values that are not numbers"])
        bad = schema.non_unit_quaternion_problem(rot, f"pose {info.name!r}: /poses/rotations",
                                                 start=start)
        if bad is not None:
            raise schema.damaged_content(self.path, [bad])
        return info, sk, np.asarray(rot, dtype=np.float64), t.root[row].copy()

    def find_poses(self, expr: str | None = None, *, take: str | None = None,
                   subject: str | None = None) -> list[PoseInfo]:
        """Poses matching a tag expression (see `posedb.tags`), a take and/or a subject."""
        rows = self._matching_rows(expr, take, subject)
        return [self._pose_info(int(r)) for r in rows]

    def search_poses(self, expr: str | None = None, *, take: str | None = None,
                     subject: str | None = None) -> list[str]:
        """Names of the poses matching, as `find_poses` selects them (the fast path)."""
        names = self._table.names
        return [names[r] for r in self._matching_rows(expr, take, subject).tolist()]

    def _matching_rows(self, expr, take, subject) -> np.ndarray:
        t = self._table
        mask = t.mask(expr)
        if take is not None:
            mask &= t.cols["take"] == _parse_id(self.take(take).id, "take-")
        if subject is not None:
            wanted = [_parse_id(k, "take-") for k, v in self._takes.items() if v.subject == subject]
            mask &= np.isin(t.cols["take"], wanted)
        return np.flatnonzero(mask)

    def find_takes(self, expr: str | None = None, *, subject: str | None = None
                   ) -> list[TakeInfo]:
        takes = self.takes()
        if subject is not None:
            takes = [t for t in takes if t.subject == subject]
        if expr is not None and expr.strip():  # (empty, or spaces: every take)
            matrix, vocab = membership([t.tags for t in takes])
            keep = compile_expression(expr)(matrix, vocab)
            takes = [t for t, k in zip(takes, keep) if k]
        return takes

    def poses(self) -> list[PoseInfo]:
        return [self._pose_info(r) for r in range(len(self._table))]

    def scenarios(self) -> list[dict]:
        """Stored scenarios (batch results): name, source, created_at, and the scenario and
        result as parsed JSON, by name."""
        out = []
        with schema.open_checked(self.path) as f:
            group = f.get("scenarios")
            for key in sorted(group) if group is not None else []:
                a = group[key].attrs
                out.append({"name": key, "source": str(a.get("source", "")),
                            "created_at": float(a.get("created_at", 0.0)),
                            "scenario": json.loads(str(a["scenario_json"])),
                            "result": json.loads(str(a["result_json"]))})
        return out

    def stats(self) -> dict:
        with schema.open_checked(self.path) as f:
            skeletons = len(f["skeletons"])
        tags = sorted(set(self._table.all_tags())
                      | {t for take in self._takes.values() for t in take.tags})
        return {
            "path": str(self.path), "schema_version": self.schema_version,
            "size_bytes": self.path.stat().st_size, "skeletons": skeletons,
            "takes": len(self._takes), "poses": len(self._table),
            "frames": sum(t.frames for t in self._takes.values()),
            "duration_s": sum(t.duration for t in self._takes.values()),
            "subjects": sorted({t.subject for t in self._takes.values() if t.subject}),
            "tags": tags,
        }

    # -- writing ------------------------------------------------------------------------------

    def check(self, *, full: bool = True) -> list[str]:
        """What is wrong with the library (empty when nothing is); see `posedb.verify`."""
        return verify(self.path, full=full)

    def check_changeable(self) -> None:
        """Refuses, with the errors a change (`edit`) would give, a library no change could be
        made to (missing, no pose library, damaged, read-only, or locked by another writer
        past the lock timeout), without changing its content (copies earlier writers left
        are removed, as before any change): for callers that store into it after long work
        and should fail before."""
        with self._writer_lock():
            self._verified_for_change(self.target)

    def _verified_for_change(self, target: Path) -> None:
        """Refuses a read-only or damaged library before a change is made to a copy of it."""
        files.check_writable(target)
        full = target.stat().st_size <= FULL_CHECK_BYTES
        with schema.open_checked(target) as f:
            problems = verify_file(f, target, full=full)
        if problems:
            raise schema.damaged_content(self.path, problems, refused_change=True)

    @contextmanager
    def edit(self) -> Iterator["Editor"]:
        """A batch of changes committed together, or not at all."""
        with self._writer_lock():
            target = self.target
            self._load()  # another writer may have committed since we read
            self._verified_for_change(target)
            try:
                with files.replacing(target) as tmp:
                    files.copy_file(target, tmp)
                    with h5py.File(tmp, "r+") as f:
                        with schema.storage_errors(self.path):
                            schema.upgrade(f)  # an older file changes in this version's layout
                        editor = Editor(self, f)
                        yield editor
                        with schema.storage_errors(self.path):
                            editor._commit()
            finally:
                self._load()

    def compact(self) -> dict:
        """Rewrites the library with only its live content, so that nothing deleted stays in
        its bytes (`posedb.compact`); returns the sizes before and after, in bytes."""
        with self._writer_lock():
            target = self.target
            self._verified_for_change(target)
            before = target.stat().st_size
            with files.replacing(target) as tmp:
                with schema.open_checked(target) as src, h5py.File(tmp, "w") as dst:
                    compact_into(src, dst)
                    schema.upgrade(dst)
            self._load()
        return {"path": str(self.path), "size_before": before,
                "size_after": self.target.stat().st_size}

    # single-change conveniences, each its own commit

    def import_bvh(self, path: str | os.PathLike | Bvh, *, unit: str | float = "auto",
                   **kw) -> TakeInfo:
        """Imports a BVH file as a take, parsed before the write lock is taken."""
        bvh = path if isinstance(path, Bvh) else read_bvh(path, unit=unit)
        with self.edit() as ed:
            tid = ed.import_bvh(bvh, **kw)
        return self.take(tid)

    def add_pose(self, take: str, frame: int, name: str, **kw) -> PoseInfo:
        with self.edit() as ed:
            pid = ed.add_pose(take, frame, name, **kw)
        return self.pose(pid)


class Editor:
    """Changes to a library inside `PoseLibrary.edit()`; names are checked before anything is
    written, and nothing reaches the library unless the whole batch succeeds."""

    def __init__(self, lib: PoseLibrary, f: h5py.File):
        self.lib = lib
        self.f = f
        self.table = lib._table.copy()
        self.takes = dict(lib._takes)
        self.next_take = lib._next_take
        self.next_pose = lib._next_pose
        self._table_dirty = False
        self._new_rotations: list[np.ndarray] = []
        self._rot_end = int(f["poses"]["rotations"].shape[0])
        self._frames_cache: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    # -- names ----------------------------------------------------------------------------

    def _check_name(self, name: str, kind: str) -> str:
        """A new take's or pose's name: takes and poses share one namespace with their ids (a
        reference names one thing: `db show NAME`, `db tag NAME` look for a pose, then a
        take)."""
        name = checked_name(name, kind)
        holder = self.name_holder(name)
        if holder is not None:
            raise DuplicateNameError(f"A {holder} already exists in {self.lib.path}")
        return name

    def _known_tags(self) -> set[str]:
        """The tags the library's takes and poses carry (a stored tag may be inherited)."""
        return set(self.table.vocab) | {t for take in self.takes.values() for t in take.tags}

    def name_holder(self, name: str) -> str | None:
        """`name_holder` of the library as this edit has it."""
        return name_holder(self.takes, self.table, name)

    def _take(self, ref: str) -> TakeInfo:
        return _find_take(self.takes, ref, self.lib.path)

    def _pose_row(self, ref: str) -> int:
        return _find_pose(self.table, ref, self.lib.path)

    def _frame_arrays(self, take: TakeInfo, frame: int) -> tuple[np.ndarray, tuple]:
        """A frame's local rotations and root position, reading small takes only once."""
        g = self.f["takes"][take.id]
        cached = self._frames_cache.get(take.id)
        if cached is None and g["local_rotations"].nbytes <= 64 << 20:
            cached = (g["local_rotations"][:], g["root_positions"][:])
            self._frames_cache[take.id] = cached
        if cached is not None:
            rot, root = cached[0][frame], cached[1][frame]
        else:
            rot, root = g["local_rotations"][frame], g["root_positions"][frame]
        return np.asarray(rot, dtype=np.float32), tuple(float(x) for x in root)

    # -- takes ----------------------------------------------------------------------------

    def _store_skeleton(self, sk: Skeleton) -> str:
        key = skeleton_key(sk)
        if key not in self.f["skeletons"]:
            schema.write_skeleton(self.f["skeletons"].create_group(key), sk)
        return key

    def add_take(self, skeleton: Skeleton, channels: np.ndarray, frame_time: float, *,
                 name: str, source: str = "", subject: str = "", tags: Iterable[str] = (),
                 notes: str = "", recorded_at: str | None = None, origin: str = "bvh",
                 frame_indices: np.ndarray | None = None,
                 received_at: np.ndarray | None = None) -> str:
        """Stores a take; returns its id.

        channels : (T, C) raw channels of `skeleton`; frame_time : s between frames;
        frame_indices : (T,) the sender's frame indices (default 0..T-1); received_at : (T,)
        Unix seconds of a streamed take. Every array is checked before anything is written
        (`schema.take_arrays`: finite, and within the range of the type it is stored as), so a
        take that would damage the library is refused with the take and the problem named.
        """
        name = self._check_name(name, "take")
        source, subject, notes = (checked_text(v, f"the {w} of take {name!r}") for v, w in
                                  ((source, "source"), (subject, "subject"), (notes, "notes")))
        tags = normalise_tags(tags, new=True, known=self._known_tags())
        if skeleton.unit_m is None:
            raise LibraryError(
                f"Expected a skeleton with a known length unit for take {name!r}: give the unit "
                "when importing (for example --unit cm)"
            )
        origin_file = str(source).split("#recording=")[0]
        what = f"take {name!r}" + (f" (from {origin_file})" if origin_file else "")
        arrays = schema.take_arrays(skeleton, channels, frame_time, what,
                                    frame_indices=frame_indices, received_at=received_at)
        frame_time = float(frame_time)
        sk_key = self._store_skeleton(skeleton)
        tid = _take_id(self.next_take)
        self.next_take += 1
        g = self.f["takes"].create_group(tid)
        recorded_at = _utc_stamp(recorded_at) if recorded_at else \
            time.strftime(UTC_STAMP, time.gmtime())
        for key, value in dict(name=name, skeleton=sk_key, frame_time=frame_time,
                               source=source, subject=subject, tags=" ".join(tags), notes=notes,
                               recorded_at=recorded_at, origin=origin).items():
            g.attrs[key] = value
        t = arrays["channels"].shape[0]
        chunk = min(t, 256)
        opts = dict(compression="gzip", compression_opts=4, shuffle=True)
        for key, data in arrays.items():
            g.create_dataset(key, data=data, chunks=(chunk,) + data.shape[1:], **opts)
        self.takes[tid] = TakeInfo(tid, name, sk_key, t, frame_time, source, subject,
                                   recorded_at, tags, notes, origin)
        return tid

    def import_bvh(self, path: str | os.PathLike | Bvh, *, name: str | None = None,
                   subject: str = "", tags: Iterable[str] = (), notes: str = "",
                   unit: str | float = "auto", joint_map: dict | None = None) -> str:
        """Imports a BVH file (or a parsed `Bvh`) as a take; returns its id. Parse a large file
        with `capture.read_bvh` before `edit()` and pass the `Bvh`: a path is parsed here,
        inside the write lock, keeping other writers waiting meanwhile. `joint_map` (role ->
        joint) is stored with the take's skeleton, so its poses retarget by it."""
        bvh = path if isinstance(path, Bvh) else read_bvh(path, unit=unit)
        source = bvh.path or ""
        default = Path(source).stem if source else "take"
        skeleton = bvh.skeleton
        if joint_map:
            from capture.jointmap import check_joint_map

            skeleton = skeleton.with_joint_map(check_joint_map(skeleton, joint_map, source))
        return self.add_take(skeleton, bvh.motion.channels, bvh.motion.frame_time,
                             name=name or default, source=source, subject=subject, tags=tags,
                             notes=notes, origin="bvh")

    def delete_take(self, ref: str) -> None:
        """Deletes a take and the poses made from it."""
        take = self._take(ref)
        num = _parse_id(take.id, "take-")
        rows = np.flatnonzero(self.table.mask(None) & (self.table.cols["take"] == num)).tolist()
        if rows:
            self.table.drop(rows)
            self._table_dirty = True
        del self.f["takes"][take.id]
        del self.takes[take.id]

    # -- poses ----------------------------------------------------------------------------

    def add_pose(self, take: str, frame: int, name: str, *, tags: Iterable[str] = (),
                 supports: Iterable[str] | str = DEFAULT_SUPPORT, notes: str = "",
                 placement: PosePlacement | None = None) -> str:
        """Adds a pose at `frame` (0-based) of `take`; returns its id. `supports` names the body
        regions the pose needs supported: regions, coarse parts or a use
        (`posedb.regions.support_regions`; default a seat's); `placement`, where the pose
        stands relative to the standard placement (None: there)."""
        info = self._take(take)
        name = self._check_name(name, "pose")
        frame = _whole(frame, "frame")
        if not 0 <= frame < info.frames:
            raise LibraryError(f"Expected a frame in 0..{info.frames - 1} of take "
                               f"{info.name!r}, got {frame}")
        notes = checked_text(notes, f"the notes of pose {name!r}")
        tags = normalise_tags(tags, new=True, known=self._known_tags())
        mask = encode_supports(supports)
        if placement is not None and not isinstance(placement, PosePlacement):
            raise LibraryError(f"Expected a PosePlacement or None as the placement of pose "
                               f"{name!r}, got {type(placement).__name__}")
        rot, root = self._frame_arrays(info, frame)
        if not (np.isfinite(rot).all() and np.isfinite(root).all()):  # (a pose copies them)
            raise schema.damaged_content(self.lib.path, [
                f"/takes/{info.id}: frame {frame}'s rotations or root position are not numbers"],
                refused_change=True)
        if schema.non_unit_quaternion(rot) is not None:
            raise schema.damaged_content(self.lib.path, [
                f"/takes/{info.id}: frame {frame}'s rotations are not unit quaternions"],
                refused_change=True)
        pid = self.next_pose
        self.next_pose += 1
        self.table.append(id=pid, name=name, take=_parse_id(info.id, "take-"), frame=frame,
                          tags=tags, supports=mask, notes=notes, created_at=time.time(),
                          rotation_start=self._rot_end, rotation_count=rot.shape[0], root=root,
                          placement=None if placement is None else
                          (*placement.offset, placement.heading))
        self._rot_end += rot.shape[0]
        self._new_rotations.append(rot)
        self._table_dirty = True
        return _pose_id(pid)

    def put_scenario(self, name: str, scenario_json: str, result_json: str, *,
                     source: str = "") -> None:
        """Stores (or replaces) a scenario and its result, both as JSON text, under `name`."""
        name = str(name).strip()
        if not name or "/" in name or any(c in name for c in "\n\r\t"):
            raise LibraryError(f"Expected a scenario name without '/' or line breaks, got "
                               f"{name!r}")
        for text, what in ((scenario_json, "scenario"), (result_json, "result")):
            try:
                json.loads(text)
            except ValueError:
                raise LibraryError(f"Expected the {what} of {name!r} as JSON text") from None
        group = self.f.require_group("scenarios")
        if name in group:
            del group[name]
        g = group.create_group(name)
        g.attrs["scenario_json"] = scenario_json
        g.attrs["result_json"] = result_json
        g.attrs["source"] = source
        g.attrs["created_at"] = time.time()

    def rename(self, ref: str, new_name: str) -> None:
        """Renames a pose or, failing that, a take."""
        try:
            row = self._pose_row(ref)
        except NotFoundError:
            try:
                self._take(ref)
            except NotFoundError:
                raise NotFoundError(f"No pose or take {ref!r} in {self.lib.path}") from None
            self.rename_take(ref, new_name)
            return
        if checked_name(new_name, "pose") == self.table.names[row]:
            return  # (its own name already: nothing to change, no clash with itself)
        self.table.rename(row, self._check_name(new_name, "pose"))
        self._table_dirty = True

    def rename_take(self, ref: str, new_name: str) -> None:
        """Renames a take (by id or name; a pose of that name is not looked at)."""
        take = self._take(ref)
        if checked_name(new_name, "take") == take.name:
            return  # (its own name already)
        new_name = self._check_name(new_name, "take")
        self.f["takes"][take.id].attrs["name"] = new_name
        self.takes[take.id] = replace(take, name=new_name)

    def tag(self, ref: str, add: Iterable[str] = (), remove: Iterable[str] = ()) -> tuple:
        """Adds and removes tags of a pose or take; returns the new tags."""
        add = set(normalise_tags(add, new=True, known=self._known_tags()))
        remove = set(normalise_tags(remove))
        try:
            row = self._pose_row(ref)
        except NotFoundError:
            try:
                take = self._take(ref)
            except NotFoundError:  # (either was looked for: "No take" alone would mislead)
                raise NotFoundError(f"No pose or take {ref!r} in {self.lib.path}") from None
            tags = tuple(sorted((set(take.tags) | add) - remove))
            self.f["takes"][take.id].attrs["tags"] = " ".join(tags)
            self.takes[take.id] = replace(take, tags=tags)
            return tags
        tags = tuple(sorted((set(self.table.tags(row)) | add) - remove))
        self.table.set_tags(row, tags)
        self._table_dirty = True
        return tags

    def set_pose(self, ref: str, *, supports: Iterable[str] | str | None = None,
                 notes: str | None = None) -> None:
        row = self._pose_row(ref)
        if supports is not None:
            self.table.set(row, "supports", encode_supports(supports))
        if notes is not None:
            self.table.set_notes(row, checked_text(notes, f"the notes of pose {ref!r}"))
        self._table_dirty = True

    def set_take(self, ref: str, *, notes: str | None = None) -> None:
        """Changes a take's notes."""
        take = self._take(ref)
        if notes is not None:
            notes = checked_text(notes, f"the notes of take {take.name!r}")
            self.f["takes"][take.id].attrs["notes"] = notes
            self.takes[take.id] = replace(take, notes=str(notes))

    def delete_pose(self, ref: str) -> None:
        self.table.drop([self._pose_row(ref)])
        self._table_dirty = True

    # -- commit ---------------------------------------------------------------------------

    def _commit(self) -> None:
        f = self.f
        f.attrs["next_take_id"] = self.next_take
        f.attrs["next_pose_id"] = self.next_pose
        if self._new_rotations:
            rot = f["poses"]["rotations"]
            new = np.concatenate(self._new_rotations)
            start = rot.shape[0]
            rot.resize((start + new.shape[0], 4))
            rot[start:] = new
        if self._table_dirty:
            self.table.write(f["poses"])
