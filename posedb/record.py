"""Live recording of a stream into the pose library, safe against a killed recorder.

The stream is written as it arrives to a journal, a raw capture (see `capture.rawcapture`) in the
folder `<library>.recordings/` next to the library, with each read going straight to the
operating system and the file forced to disk every half second. When the recording ends, the
journal becomes a take in one library commit and is then removed. A recorder killed at any
moment leaves the library untouched and the journal holding everything received up to the
kill; `recover` turns such journals into takes (no more frames than the recording's frame
limit, which its journal keeps). The library itself is never held open during a
recording, so other processes can list and read it, and several streams can be recorded at once.

A recorder holds its journal's lock (`<journal>.lock`, see `posedb.locking`) from the first
frame until the take is stored and the journal removed; `recover` takes the same lock before it
stores a journal, so the two never both store one. The final commit waits for other writers of
the library like any change; should it still fail, the journal stays and the error says which
command stores it.

Several people in suits are never mixed into one take (Axis sends one frame per avatar per
sample, interleaved on one stream): the journal keeps every byte, and its import keeps each
avatar apart, the avatar chosen when the recording started alone, or, without a choice, each
avatar as a take of its own (`import_journal_takes`), all in the one commit.

Poses can be marked while a take records (`TakeRecorder.mark`): each mark is a record of the
journal itself (kind "mark", at the receive time of the frame marked), so it survives what the
frames survive, and becomes a pose of the take in the same commit that stores the take.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shlex
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Mapping

import numpy as np

from capture import parse_bvh, read_bvh, resolve_path
from capture.avatars import (AvatarKey, AvatarNotSeenError, avatar_selector, avatar_take_names,
                             describe_avatars, split_by_avatar)
from capture.cli_output import check_limits
from capture.files import write_atomic
from capture.monitor import StreamMonitor, sender_timing
from capture.rawcapture import (MARK, RawCaptureError, RawCaptureWriter, raw_header,
                                raw_marks, skeleton_header_text)
from capture.sources import RawFileTransport, Source, UnknownProtocolError, open_transport
from capture.stream_layout import StreamLayout

from .library import (DuplicateNameError, Editor, PoseLibrary, TakeInfo, checked_name,
                      checked_text, derived_name)
from .locking import LockedError, exclusive, lock_path, try_exclusive
from .regions import DEFAULT_SUPPORT, support_regions
from .schema import InvalidDataError, LibraryError
from .tags import normalise_tags

# `import_journal_takes` keeps the avatar chosen when the recording started
AS_RECORDED = object()

_SYNC_EVERY = 0.5  # seconds between fsyncs of the journal
_COMMON_RATES = (24, 25, 30, 48, 50, 60, 90, 96, 100, 120, 125, 200, 240, 250)


def journal_dir(library: str | os.PathLike) -> Path:
    library = Path(library)
    return library.with_name(library.name + ".recordings")


def _journal_name(take: str) -> str:
    slug = re.sub(r"[^A-Za-z0-9_.-]+", "_", take)[:80] or "take"
    return f"{slug}-{uuid.uuid4().hex[:8]}.raw"


def _locked_by_someone(path: Path) -> bool:
    """Whether a live recorder (or a `recover`) holds the journal's lock."""
    lock = try_exclusive(path)
    if lock is None:
        return True
    lock.release()
    return False


class _AlreadyStored(Exception):
    """Raised inside an edit to leave the library untouched: the takes exist already."""

    def __init__(self, take_ids: list[str]):
        self.take_ids = take_ids


def _storable_names(take: str, names: dict) -> dict:
    """The avatars' take names (`avatar_take_names`), each one the library takes
    (`checked_name`): a name derived from a long take name or shaped like an id (`take` and
    an avatar named `00002`) becomes `<take>-avatar<index>`, the take's part shortened to fit
    (`derived_name`; the recording's take name was checked when it began; its avatars' names
    were not)."""
    out = {}
    for key, name in names.items():
        try:
            out[key] = checked_name(name, "take")
        except LibraryError:
            out[key] = checked_name(derived_name(take, f"-avatar{key.index}"), "take")
    return out


def _stored_takes(takes: Iterable[TakeInfo], recording_id: str
                  ) -> list[tuple[AvatarKey | None, TakeInfo]]:
    """The takes a recording already became (one per avatar), as (None, take)."""
    return [(None, take) for take in takes
            if recording_id and take.source.endswith(f"#recording={recording_id}")]


@dataclass(frozen=True)
class Recording:
    """A journal in `<library>.recordings/`: a recording running, or one a killed recorder left.

    unseen_avatar : for a journal `recover` refused because the avatar chosen when it was
        recorded never came (kept for a choice of avatar), what it said and what to run to
        store it; empty otherwise. avatars : the avatars that came then, with their frames.
    """

    path: Path
    take: str
    source: str
    started_at: str
    size_bytes: int
    running: bool
    unseen_avatar: str = ""
    avatars: tuple = ()

    def as_dict(self) -> dict:
        if self.running:
            state = "recording"
        elif self.unseen_avatar:
            state = f"waiting for a choice of avatar: {self.unseen_avatar}"
        else:
            state = "interrupted (run `sitrelax db recover`)"
        row = {"kind": "recording", "name": self.take, "journal": str(self.path),
               "source": self.source, "started_at": self.started_at,
               "size_bytes": self.size_bytes, "state": state, "tags": []}
        if self.unseen_avatar and not self.running:
            row["avatars"] = list(self.avatars)
        return row


def recordings(library: str | os.PathLike) -> list[Recording]:
    """Journals of recordings running or interrupted, oldest first."""
    folder = journal_dir(library)
    out = []
    for note in sorted(folder.glob("*.raw.unseen-avatar.json")) if folder.is_dir() else []:
        if not note.with_name(note.name[:-len(".unseen-avatar.json")]).exists():
            try:  # (its journal deleted by hand, as the advice says)
                note.unlink(missing_ok=True)
            except OSError:  # (a library this process may only read: the note stays, unread)
                pass
    for path in sorted(folder.glob("*.raw")) if folder.is_dir() else []:
        try:
            header = raw_header(path)
            size = path.stat().st_size
        except (RawCaptureError, OSError):
            continue
        take = header.get("take", {}).get("name", path.stem)
        note = _unseen_avatar_note(path, size)
        unseen = "" if note is None else \
            f"{note['what']} {_unseen_avatar_advice(library, path, take)}"
        out.append(Recording(path, take, header.get("source", ""), header.get("started_at", ""),
                             size, _locked_by_someone(path), unseen,
                             tuple(note.get("avatars", ())) if note else ()))
    return out


def _note_path(journal: Path) -> Path:
    """Where `recover` notes that it refused `journal` for an avatar that never came."""
    return journal.with_name(journal.name + ".unseen-avatar.json")


def _unseen_avatar_note(journal: Path, size: int) -> dict | None:
    """`recover`'s note on `journal` ({"what", "avatars", "size_bytes"}), or None: none, one
    that cannot be read, or one of the journal as it was at another size."""
    try:
        note = json.loads(_note_path(journal).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if (not isinstance(note, dict) or not isinstance(note.get("what"), str)
            or note.get("size_bytes") != size or not isinstance(note.get("avatars", []), list)):
        return None
    return note


def _unseen_avatar_advice(library: str | os.PathLike, journal: Path, take: str) -> str:
    """What stores a journal whose chosen avatar never came (`recover` with a choice)."""
    command = (f"sitrelax db recover --db {shlex.quote(str(Path(library)))} "
               f"--journal {shlex.quote(str(journal))}")
    return (f"To store it, run `{command}` with --avatar NAME_OR_INDEX (one of those, as "
            f"take {take!r}) or --every-avatar (each avatar as a take of its own); delete the "
            "journal to drop the recording")


def _frame_time(frames, header_frame_time: float) -> float:
    """The stream's frame period: from the sender's indices and arrival times (split into
    segments where the index restarts), snapped to a common rate within 2 %; the header's
    frame time when the stream cannot tell (too few frames, receive times that are not all
    finite, a period no BVH file could give). The take's one check (`schema.take_arrays`)
    refuses the receive times themselves when they are not finite."""
    from capture.bvh import MAX_FRAME_TIME, MIN_FRAME_TIME

    received = np.array([f.received_at for f in frames], dtype=np.float64)
    if not np.isfinite(received).all():
        return header_frame_time
    idx = [f.frame_index for f in frames if f.frame_index is not None]
    t = [f.received_at for f in frames if f.frame_index is not None]
    period = sender_timing(idx, t)[0]
    if period is None and len(frames) >= 2:
        period = float(np.median(np.diff(received)))
    if period is None or not MIN_FRAME_TIME <= period <= MAX_FRAME_TIME:
        return header_frame_time
    rate = 1.0 / period
    best = min(_COMMON_RATES, key=lambda r: abs(r - rate))
    return 1.0 / best if abs(best - rate) <= 0.02 * best else period


def import_journal(lib: PoseLibrary, path: Path, limit: int | Mapping | None = None
                   ) -> TakeInfo | None:
    """Turns a journal into its take(s) (or finds those it already became) and removes it;
    the first take, or None for a journal that holds no frame (it is removed too). See
    `import_journal_takes`, which returns every take."""
    takes = import_journal_takes(lib, path, limit)
    return takes[0][1] if takes else None


def _limited(groups: dict[AvatarKey, list], limit: int | Mapping | None) -> dict:
    """Each avatar's frames cut to its limit: an int for every avatar, a mapping from
    `AvatarKey` to a count (0 for an avatar it lacks), or None for no limit."""
    if limit is None:
        return groups
    if isinstance(limit, Mapping):
        cut = {k: frames[:max(int(limit.get(k, 0)), 0)] for k, frames in groups.items()}
    else:
        cut = {k: frames[:max(int(limit), 0)] for k, frames in groups.items()}
    return {k: frames for k, frames in cut.items() if frames}


def _recorded_limit(path: Path, frame_limit: object, frames: list, selector
                    ) -> dict[AvatarKey, int] | None:
    """The frames of each avatar a recording with `frame_limit` (`record`'s `frames`, from
    its journal; None: no limit) counted when it stopped: those up to the frame that brought
    a kept avatar to the limit, counted as its recorder counts them (`StreamMonitor`)."""
    if frame_limit is None:
        return None
    if isinstance(frame_limit, bool) or not isinstance(frame_limit, int) or frame_limit < 1:
        raise LibraryError(f"{path}: expected the journal's frame limit as a whole number >= 1 "
                           f"or null, got {frame_limit!r}")
    monitor = StreamMonitor(selector)
    monitor.add_up_to(frames, frame_limit)
    return {k: n for k, n in monitor.avatars.items() if monitor.kept(k)}


def import_journal_takes(lib: PoseLibrary, path: Path, limit: int | Mapping | None = None,
                         *, avatar: object = AS_RECORDED) -> list[tuple[AvatarKey, TakeInfo]]:
    """Turns a journal into takes (or finds those it already became) and removes it.

    The frames of each avatar on the stream are kept apart (Axis sends one frame per avatar
    per sample when several people wear suits): with the avatar chosen when the recording
    started (the journal's `take.avatar`), that avatar's frames become the take; without one,
    each avatar becomes a take of its own (`capture.avatars.avatar_take_names`: the take's
    name when one avatar came, else `<take>-<avatar name>`), all stored in one commit.

    limit : the frames of each avatar its recorder counted, which its take holds at most (the
        journal holds every byte received, so a frame whose bytes came with the last one
        counted may be whole in it too): an int for every avatar, a mapping from `AvatarKey`
        to a count, or None for the frames up to the recording's frame limit (`record`'s
        `frames`, in the journal's `take.frame_limit`: the frames up to the one that brought
        a kept avatar to it, where its recorder stops) or, without one (a journal made before
        the limit was written into journals), all.
    avatar : the avatar to keep in place of the one chosen when the recording started (a name
        or an index; None: every avatar, as without a choice); `AS_RECORDED` for that choice.

    Returns [(avatar, take)] in the order the avatars first appeared; [] for a journal that
    holds no frame (it is removed too). A chosen avatar of which no frame came raises
    `capture.avatars.AvatarNotSeenError` naming the avatars that did; the journal stays.
    """
    header = raw_header(path)
    meta = header.get("take", {})
    recording_id = meta.get("recording_id", "")
    stored = _stored_takes(lib.takes(), recording_id)
    if stored:
        path.unlink()  # the takes were stored; only the journal's removal was missed
        return stored
    if not isinstance(header.get("skeleton_bvh"), str):
        raise LibraryError(f"{path}: the journal's header holds no skeleton, so its frames "
                           "cannot be read")
    asked = avatar_selector(meta.get("avatar"))
    selector = asked if avatar is AS_RECORDED else avatar_selector(avatar)
    unit = meta.get("unit_m")
    skeleton = parse_bvh(header["skeleton_bvh"], unit=unit if unit else "auto").skeleton
    layout = StreamLayout(skeleton)
    with Source(RawFileTransport(path), layout) as source:
        frames = list(source)
    if limit is None:
        limit = _recorded_limit(path, meta.get("frame_limit"), frames, selector)
    seen = split_by_avatar(frames)
    groups = _limited(seen, limit)
    if selector is not None:
        groups = {k: v for k, v in groups.items() if selector.matches(k)}
        if not groups and frames and not any(selector.matches(k) for k in seen):
            raise selector.not_seen({k: len(v) for k, v in seen.items()}, takes=True)
    if not groups:
        path.unlink()
        return []
    names = _storable_names(str(meta.get("name", path.stem)),
                            avatar_take_names(str(meta.get("name", path.stem)), groups))
    per_avatar = {(a["index"], a["name"]): a for a in source.decoder.stats.avatar_dicts()}
    stats = source.stats()
    marks = raw_marks(path)
    notes = meta.get("notes", "")
    others = {k: len(v) for k, v in seen.items() if k not in groups}
    asked_note = ""
    if asked is not None and not any(asked.matches(k) for k in seen):
        chosen = "every avatar" if selector is None else f"avatar {selector.text!r}"
        asked_note = (f"; recorded with --avatar {asked.text!r}, of which no frame came, and "
                      f"stored by `sitrelax db recover` choosing {chosen}")
    several = len(seen) > 1 or selector is not None
    try:
        with lib.edit() as ed:
            stored = _stored_takes(ed.takes.values(), recording_id)  # as of the lock
            if stored:
                raise _AlreadyStored([take.id for _, take in stored])
            made = []
            first = next(iter(groups))
            for key, group in groups.items():
                dropped = per_avatar.get((key.index, key.name), {}).get("dropped", 0)
                summary = (f"recorded from {header.get('source', '?')}: {len(group)} frames, "
                           f"{dropped} dropped, {stats['corrupt']} corrupt")
                if several:
                    summary += f"; avatar {key.label}"
                    if len(groups) > 1:
                        summary += (f", one of {len(groups)} avatars recorded together (takes "
                                    f"{', '.join(repr(n) for n in names.values())})")
                    if others:
                        summary += (f"; the stream also carried {describe_avatars(others)}, "
                                    "not kept")
                summary += asked_note
                wanted = names[key]
                name = _free(ed, wanted)
                if name != wanted:  # (another take took it while this one recorded)
                    summary += f"; stored as {name!r}: a take named {wanted!r} was there first"
                channels = np.array([source.channels(f) for f in group], dtype=np.float32)
                indices = np.array([f.frame_index if f.frame_index is not None else k
                                    for k, f in enumerate(group)], dtype=np.int64)
                received = np.array([f.received_at for f in group], dtype=np.float64)
                tid = ed.add_take(
                    skeleton, channels,
                    _frame_time(group, float(meta.get("frame_time", 1 / 120))),
                    name=name, subject=meta.get("subject", ""),
                    tags=meta.get("tags", ()), notes=(notes + "\n" if notes else "") + summary,
                    source=f"{header.get('source', '')}#recording={recording_id}",
                    recorded_at=header.get("started_at"), origin="stream",
                    frame_indices=indices, received_at=received,
                )
                mine = [(t, m) for t, m in marks if _mark_avatar(m, groups, first) == key]
                _add_marked_poses(ed, tid, received, mine)
                made.append((key, tid))
    except _AlreadyStored as done:
        path.unlink()
        return [(None, lib.take(tid)) for tid in done.take_ids]
    path.unlink()
    return [(key, lib.take(tid)) for key, tid in made]


def _mark_avatar(mark: dict, groups: Mapping, first: AvatarKey) -> AvatarKey:
    """The avatar whose take a mark belongs to: the one it names (the avatar on screen when
    it was made), else the first avatar."""
    who = mark.get("avatar")
    if isinstance(who, dict):
        key = AvatarKey(who.get("index"), who.get("name"))
        if key in groups:
            return key
    return first


def marked_frame(received_at: np.ndarray, t: float) -> int:
    """The take frame a mark at receive time `t` names: the last frame received by then (the
    one shown when the mark was made), or the first if none was.

    received_at : (T,) Unix s, non-decreasing (the take's receive times).
    """
    return max(0, int(np.searchsorted(received_at, t, side="right")) - 1)


def _free(ed: Editor, name: str) -> str:
    """`name` or the first of `name-2`, `name-3`... that no take or pose holds (`name_holder`):
    a recording, or a pose marked in it, is never lost to a name taken while it ran; the take's
    notes say what was renamed. A name near the length limit is shortened before its suffix
    (`derived_name`), so that the new name is one the library takes."""
    if ed.name_holder(name) is None:
        return name
    k = 2
    while ed.name_holder(derived_name(name, f"-{k}")) is not None:
        k += 1
    return derived_name(name, f"-{k}")


def _add_marked_poses(ed: Editor, take_id: str, received_at: np.ndarray,
                      marks: list[tuple[float, dict]]) -> None:
    """The journal's marks as poses of the new take (inside the commit that stores it)."""
    take = ed.takes[take_id]
    renamed = []
    for t, mark in marks:
        frame = marked_frame(received_at, t)
        wanted = str(mark.get("name") or derived_name(take.name, f"-f{frame:05d}"))
        name = _free(ed, wanted)
        if name != wanted:
            renamed.append(f"the pose marked {wanted!r} is {name!r} (the name was taken)")
        ed.add_pose(take_id, frame, name, tags=tuple(take.tags) + tuple(mark.get("tags", ())),
                    supports=mark.get("supports") or DEFAULT_SUPPORT,
                    notes=str(mark.get("notes", "")))
    if renamed:
        ed.set_take(take_id, notes="\n".join([take.notes, *renamed]))


def _drop_leftovers(journal: Path) -> None:
    """Removes a stored journal's lock file (released: nothing takes it again once the journal
    is gone) and `recover`'s note on it; a journal still there keeps them."""
    if journal.exists():
        return
    for path in (lock_path(journal), _note_path(journal)):
        try:
            os.unlink(path)
        except OSError:
            pass


def _unseen_avatar(lib: PoseLibrary, rec: Recording, exc: AvatarNotSeenError) -> dict:
    """The row of a journal whose chosen avatar never came: refused (nothing of it is stored,
    as its recorder would have stored nothing), naming the avatars that came, with how to
    store them. The journal stays, unlike at a recorder's refusal: no one saw this one when
    the stream came, and the recording may be of the avatar meant under another name. A
    note beside it (called with the journal's lock held) lets `recordings` say so, and what
    it needs, rather than send the user to `recover` again."""
    advice = _unseen_avatar_advice(lib.path, rec.path, rec.take)
    try:
        write_atomic(_note_path(rec.path), json.dumps(
            {"what": exc.what, "avatars": exc.avatars,
             "size_bytes": rec.path.stat().st_size}).encode())
    except OSError:
        pass  # (only `db list`'s wording depends on it: `recover` refuses the journal again)
    return {"status": f"failed: {exc.what} {advice}", "avatars": exc.avatars}


def _recover_one(lib: PoseLibrary, rec: Recording, avatar: object = AS_RECORDED) -> dict:
    """Stores one journal, holding its lock so that its recorder (if it is finishing) and any
    other `recover` wait or skip it; `avatar` as in `import_journal_takes`."""
    row = {"journal": str(rec.path), "take": rec.take}
    lock = try_exclusive(rec.path)
    if lock is None:
        return row | {"status": "still recording"}
    try:
        if not rec.path.exists():  # its recorder stored it meanwhile
            return row | {"status": "stored by its recorder"}
        takes = [take for _, take in import_journal_takes(lib, rec.path, avatar=avatar)]
    except AvatarNotSeenError as exc:
        return row | _unseen_avatar(lib, rec, exc)
    except (ValueError, OSError) as exc:  # (LibraryError and RawCaptureError among them)
        return row | {"status": f"failed: {exc}"}
    finally:
        lock.release()
        _drop_leftovers(rec.path)
    if not takes:
        status = "empty, removed"
    elif len(takes) > 1:
        status = (f"recovered as {', '.join(repr(t.name) for t in takes)} (one take per "
                  "avatar)")
    elif takes[0].name == rec.take:
        status = "recovered"
    else:
        status = f"recovered as {takes[0].name!r} (a take named {rec.take!r} was there first)"
    return row | {"status": status, "frames": sum(t.frames for t in takes),
                  "takes": [t.name for t in takes]}


def recover(library: str | os.PathLike, *, journal: str | os.PathLike | None = None,
            avatar: object = AS_RECORDED, lock_timeout: float | None | str = "default",
            on_wait: Callable[[float], None] | None = None) -> list[dict]:
    """Imports the journals that killed recorders left; skips those still being written.

    A journal recorded with a chosen avatar of which no frame came is refused (its row's
    status says so, naming the avatars that came, and `avatars` lists them with their
    frames) and kept: `journal` (its path) with `avatar` (a name or an index, or None for
    every avatar, each as a take of its own) stores it. `journal` alone recovers that journal
    only; `avatar` applies to one journal, so it needs `journal`.
    """
    if avatar is not AS_RECORDED:
        if journal is None:
            raise LibraryError("Expected the journal whose avatar to choose (--journal), got "
                               "none: an avatar applies to one recording")
        avatar_selector(avatar)  # refused now (an empty name) rather than at the import
    found = recordings(library)
    if journal is not None:
        wanted = Path(journal).resolve()
        found = [r for r in found if r.path.resolve() == wanted]
        if not found:
            raise LibraryError(f"Expected a journal of an interrupted recording in "
                               f"{journal_dir(library)}, got {journal}")
    lib = PoseLibrary(library, lock_timeout=lock_timeout, on_wait=on_wait)
    return [{"journal": str(r.path), "take": r.take, "status": "still recording"} if r.running
            else _recover_one(lib, r, avatar) for r in found]


def _store_journal(lib: PoseLibrary, journal: Path, take: str,
                   limit: int | Mapping | None = None) -> list[tuple[AvatarKey, TakeInfo]]:
    """The recording's final commit (of each avatar's first `limit` frames, see
    `import_journal_takes`); on failure the journal stays and the error says so (and, unless
    its data was refused, which command stores it)."""
    try:
        return import_journal_takes(lib, journal, limit)
    except AvatarNotSeenError:
        raise  # (the journal stays; the error names the avatars that came)
    except (ValueError, OSError) as exc:  # (LibraryError and RawCaptureError among them)
        if not journal.exists():
            raise
        if isinstance(exc, InvalidDataError):  # (`recover` would refuse it again)
            raise LibraryError(f"The recording of take {take!r} was not stored in {lib.path} "
                               f"({exc}); it is kept as received in {journal}") from exc
        why = "another writer kept the library locked" if isinstance(exc, LockedError) else exc
        raise LibraryError(
            f"The recording of take {take!r} was not stored in {lib.path} ({why}); it is kept "
            f"in {journal}: run `sitrelax db recover --db {lib.path}` to store it"
        ) from exc


class TakeRecorder:
    """One take being recorded: its journal (its lock held from the start until the take is
    stored), the poses marked meanwhile, and the final commit.

    Whoever reads the stream gives the journal to its `Source` (``raw=recorder.writer``) and
    calls `tick()` after each read (the journal is forced to disk every half second);
    `finish()` stores the take, with its marked poses, in one commit. `record` drives one
    from a source URL; the studio drives one from the stream it shows. A recorder that is
    dropped without `finish()` (a crash) leaves its journal for `recover`.

    Parameters
    ----------
    library : the pose library's path (made if missing).
    take : the new take's name; refused at once when a take or a recording holds it.
    skeleton : the BVH header paired with the stream (path or ``bundled:NAME``).
    source_url : where the stream comes from (stored with the take).
    datagram : whether the transport delivers datagrams (UDP) rather than a byte stream.
    avatar : the avatar to keep (its name, or its index), or None to keep every avatar on the
        stream, each as a take of its own when several come (see `import_journal_takes`).
    frames : the frames of one avatar the recording stops at (see `record`), or None: written
        into the journal, so that a journal its recorder never stored (`recover`) becomes
        the takes the recorder would have stored, of no more frames than were asked for.
    """

    def __init__(self, library: str | os.PathLike, take: str, skeleton: str, source_url: str,
                 *, datagram: bool = False, subject: str = "", tags: Iterable[str] = (),
                 notes: str = "", unit: str | float = "auto",
                 on_event: Callable[[str], None] | None = None,
                 lock_timeout: float | None | str = "default", avatar: str | int | None = None,
                 frames: int | None = None):
        def waiting(seconds: float) -> None:
            if on_event is not None and (int(seconds) == 1 or int(seconds) % 5 == 0):
                on_event(f"waiting {seconds:.0f} s for another writer of {library} to finish")

        self.take = checked_name(take, "take")
        # checked now, not at the final commit: a recording whose take could never be stored;
        # and before the library is made, so that a refused recording writes nothing
        subject = checked_text(subject, f"the subject of take {self.take!r}")
        notes = checked_text(notes, f"the notes of take {self.take!r}")
        checked_text(source_url, f"the source of take {self.take!r}")
        tags = normalise_tags(tags, new=True)
        check_limits(None, frames, LibraryError)
        self.selector = avatar_selector(avatar)
        if self.selector is not None:
            checked_text(self.selector.text, "the avatar")
        header_path = resolve_path(skeleton)
        header = read_bvh(header_path, unit=unit)
        if header.skeleton.unit_m is None:
            raise LibraryError(f"{header_path}: the skeleton's length unit is unknown; pass "
                               "--unit")
        self.library = PoseLibrary(library, create=True, lock_timeout=lock_timeout,
                                   on_wait=waiting)
        self._check_free(library)
        self.skeleton = header.skeleton
        self.layout = StreamLayout(header.skeleton)
        folder = journal_dir(library)
        folder.mkdir(exist_ok=True)
        self.journal = folder / _journal_name(self.take)
        meta = {"name": self.take, "subject": subject, "tags": list(tags), "notes": notes,
                "recording_id": uuid.uuid4().hex, "unit_m": header.skeleton.unit_m,
                "frame_time": header.motion.frame_time, "pid": os.getpid(),
                "avatar": None if self.selector is None else self.selector.text,
                "frame_limit": None if frames is None else int(frames)}
        self._held = contextlib.ExitStack()
        # held until the take is stored: tells `recover` this journal is alive
        self._held.enter_context(exclusive(self.journal, timeout=10.0, what="The journal"))
        try:
            self.writer = RawCaptureWriter(
                self.journal, source=source_url, time_origin=time.time(),
                transport="datagram" if datagram else "stream",
                skeleton_bvh=skeleton_header_text(header_path.read_text(errors="replace")),
                extra={"take": meta})
        except BaseException:
            self._held.close()
            raise
        if not self.library.takes():
            self._keep_library(on_event)
        self.marks: list[dict] = []
        self.stored: list[tuple[AvatarKey, TakeInfo]] = []  # once `finish` stored them
        self._next_sync = time.monotonic() + _SYNC_EVERY

    def _keep_library(self, on_event: Callable[[str], None] | None) -> None:
        """Makes sure the library this recording goes into still exists, now that its journal
        does. An import that made the library and failed removes it when it holds nothing
        (`posedb.cli`), under the library's lock and only while no journal is beside it: it
        may have looked before this journal was made. Waiting for the lock lets such a
        removal finish; the library is then made again, empty, if it went. Only an empty
        library is ever removed, so only one is waited for. On failure the journal goes."""
        try:
            if self.library.make_again_if_removed() and on_event is not None:
                on_event(f"made {self.library.path} again: a failed import removed it as "
                         "this recording started")
        except BaseException:
            try:
                self.writer.close()
                self.journal.unlink(missing_ok=True)
            finally:
                self._held.close()
                _drop_leftovers(self.journal)
            raise

    def _check_free(self, library) -> None:
        holder = self.library.name_holder(self.take)
        if holder is not None:
            raise DuplicateNameError(f"A {holder} already exists in {self.library.path}")
        if any(r.take == self.take for r in recordings(library)):
            raise DuplicateNameError(f"A recording of take {self.take!r} is already running or "
                                     "waiting for `sitrelax db recover`")

    def tick(self) -> None:
        """Forces the journal to disk when half a second has passed since the last time."""
        now = time.monotonic()
        if now >= self._next_sync:
            self.writer.sync()
            self._next_sync = now + _SYNC_EVERY

    def mark(self, received_at: float, *, name: str = "", tags: Iterable[str] = (),
             supports: Iterable[str] | str = DEFAULT_SUPPORT, notes: str = "",
             avatar: AvatarKey | None = None) -> dict:
        """Marks the frame received at `received_at` (Unix s; the frame on screen) as a pose.

        The mark is written to the journal at once (and forced to disk): it becomes a pose of
        the take, carrying the take's tags and `tags`, when the take is stored. An empty name
        becomes "<take>-fNNNNN" (its frame; the take's name shortened to keep it within the
        library's 200 characters, `derived_name`). Names, tags and supports are checked now, a
        name against the library's poses and the marks before. `avatar`: the avatar of the frame
        marked, whose take the pose goes to when several avatars are recorded (None: the
        first avatar's). Returns the mark as stored, with its `received_at`.
        """
        if not np.isfinite(received_at):
            raise LibraryError(f"Expected the receive time of a frame, got {received_at!r}")
        name = checked_name(name, "pose") if str(name).strip() else ""
        holder = self.library.name_holder(name) if name else None
        if holder is not None:
            raise DuplicateNameError(f"A {holder} already exists in {self.library.path}")
        if name and any(m["name"] == name for m in self.marks):
            raise DuplicateNameError(f"A pose named {name!r} was marked already")
        mark = {"name": name, "tags": list(normalise_tags(tags, new=True)),
                "supports": list(support_regions(supports)),
                "notes": checked_text(notes, "the notes of a marked pose")}
        if avatar is not None:
            mark["avatar"] = {"index": int(avatar.index), "name": str(avatar.name)}
        self.writer.write(MARK, float(received_at), json.dumps(mark).encode("utf-8"))
        self.writer.sync()
        mark["received_at"] = float(received_at)
        self.marks.append(mark)
        return mark

    def finish(self, frames: int | Mapping | None = None) -> TakeInfo | None:
        """Closes the journal and stores it as the take(s) with the marked poses, in one
        commit; returns the first take (None when no frame came), every take (one per avatar
        kept) is in `stored`. On failure the journal stays and the error says how to store
        it. The journal's lock is released either way. `frames`: the frames of each avatar
        the reader counted (an int, or a mapping from `AvatarKey`), which its take holds (the
        journal may hold more whole frames than were read: every byte received); None for
        every frame in the journal up to the recording's frame limit (`frames`), if any."""
        try:
            self.writer.close()
            try:
                self.stored = _store_journal(self.library, self.journal, self.take, frames)
            except AvatarNotSeenError:
                # a recording of other people than the one asked for: nothing is written
                self.journal.unlink(missing_ok=True)
                raise
            return self.stored[0][1] if self.stored else None
        finally:
            self._held.close()
            _drop_leftovers(self.journal)

    def abandon(self) -> None:
        """Closes the journal and releases its lock without storing it, as a recorder that
        died would leave it: `recover` stores it (with its marks) later."""
        try:
            self.writer.close()
        finally:
            self._held.close()

    def discard(self) -> None:
        """Drops a journal that can never become a take (no frame of the protocol in it)."""
        try:
            self.writer.close()
            self.journal.unlink(missing_ok=True)
        finally:
            self._held.close()
            _drop_leftovers(self.journal)


def record(source_url: str, library: str | os.PathLike, take: str, skeleton: str, *,
           duration: float | None = None, frames: int | None = None, subject: str = "",
           tags: Iterable[str] = (), notes: str = "", unit: str | float = "auto",
           fmt: str = "auto", avatar: str | int | None = None,
           on_event: Callable[[str], None] | None = None,
           on_progress: Callable[[dict], None] | None = None,
           stop: Callable[[], bool] | None = None,
           lock_timeout: float | None | str = "default") -> dict:
    """Records a stream into a new take; returns the listener's summary plus the take(s).

    Stops after `duration` seconds, `frames` frames, the end of a `file:` source, or when
    `stop()` returns true. The final commit waits up to `lock_timeout` s for other writers
    (reported through `on_event`). A `duration` that is not a number of seconds > 0 or `frames`
    that is not a whole number >= 1 is refused before anything is written.

    Avatars (several people in suits: Axis sends one frame per avatar per sample) are never
    mixed. `avatar` (a name such as ``"Avatar01"``, or an index) keeps that avatar alone, in
    the take `take`; without it every avatar is kept, and when several come each becomes a
    take of its own, `<take>-<avatar name>` (one avatar: the take is `take`). `frames` counts
    the frames of one avatar (the kept one, or the first to reach it). A chosen avatar that
    never came while others did raises `capture.avatars.AvatarNotSeenError` naming those that
    came; nothing is stored and the journal is removed.

    The summary holds the listener's counters (those of the kept avatar with `avatar`),
    `avatars` (each avatar seen: index, name, frames, dropped, restarts, kept, and `take`, the
    name of the take it became or None), `take` (the first take, or None), `takes` (every
    take) and `library`.
    """
    check_limits(duration, frames, LibraryError)
    transport = open_transport(source_url)
    try:
        recorder = TakeRecorder(library, take, skeleton, source_url,
                                datagram=transport.datagram, subject=subject, tags=tags,
                                notes=notes, unit=unit, on_event=on_event,
                                lock_timeout=lock_timeout, avatar=avatar, frames=frames)
    except BaseException:
        transport.close()
        raise
    try:
        summary, counted = _receive(Source(transport, recorder.layout, fmt=fmt,
                                           raw=recorder.writer, on_event=on_event),
                                    recorder, duration, frames, on_progress, stop)
    except UnknownProtocolError:
        recorder.discard()  # nothing of it can become a take
        raise
    try:
        recorder.finish(counted)
    except AvatarNotSeenError as exc:
        exc.avatars = [{k: r[k] for k in ("index", "name", "frames")}
                       for r in summary["avatars"]] or exc.avatars
        raise
    takes = {key: info for key, info in recorder.stored}
    for row in summary["avatars"]:
        info = takes.get(AvatarKey(row["index"], row["name"]))
        row["take"] = None if info is None else info.name
    summary["takes"] = [info.as_dict() for _, info in recorder.stored]
    summary["take"] = summary["takes"][0] if summary["takes"] else None
    summary["library"] = str(recorder.library.path)
    return summary


def _receive(source: Source, recorder: TakeRecorder, duration, frames, on_progress,
             stop) -> tuple[dict, dict[AvatarKey, int]]:
    """Reads `source` into its journal until a limit, `stop()` or its end; the summary and
    the frames of each kept avatar counted (what its take holds)."""
    monitor = StreamMonitor(recorder.selector)
    start = time.monotonic()
    next_report = start + 1.0
    with source as src:
        while not src.exhausted:
            left = None if duration is None else duration - (time.monotonic() - start)
            if (left is not None and left <= 0) or (stop is not None and stop()):
                break
            got = src.read(0.1 if left is None else max(0.0, min(0.1, left)))
            reached = monitor.add_up_to(got, frames)
            recorder.tick()
            now = time.monotonic()
            if on_progress is not None and now >= next_report:
                next_report += 1.0
                on_progress(monitor.summary(src.stats()))
            if reached:
                break
        summary = monitor.summary(src.stats())
        counted = {k: n for k, n in monitor.avatars.items() if monitor.kept(k)}
        summary["frames"] = sum(counted.values())
        summary["events"] = [m for _, m in src.events]
    return summary, counted
