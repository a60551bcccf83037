"""`sitrelax db ...` and `sitrelax capture record`: the pose library from the command line."""

from __future__ import annotations

import json
import os
import signal
import sys

from capture.cli_output import number, print_event, print_status

# the library (numpy, h5py) loads when a command runs: `sitrelax --help` stays fast
from .constants import DEFAULT_MAX_SPEED, DEFAULT_MIN_DURATION, MAX_HOLD_DURATION
from .regions import BODY_REGIONS, DEFAULT_SUPPORT, SUPPORT_GROUPS, SUPPORT_NAMES, SUPPORT_USES

DEFAULT_DB = os.environ.get("SITRELAX_DB", "poses.h5")


def _json(obj) -> str:
    """`obj` as JSON text, refusing a number that is not finite (JSON has none: `NaN` would
    break the reader) with an error that says where to look."""
    try:
        return json.dumps(obj, indent=2, allow_nan=False)
    except ValueError:
        from .schema import LibraryError

        raise LibraryError("Expected finite numbers to write as JSON, got NaN or infinity (a "
                           "damaged library? `sitrelax db check` lists what is wrong)") from None


def _print(obj, as_json: bool, text: str) -> None:
    print(_json(obj) if as_json else text)


def add_lock_timeout_option(parser, when: str = "") -> None:
    """A command's `--lock-timeout S` (read with `posedb.locking.lock_timeout_of`); `when`:
    what it applies to, as a help text's start ("with --save: ")."""
    parser.add_argument("--lock-timeout", type=float, default=None, metavar="S",
                        help=f"{when}seconds to wait for another writer of the library, "
                             f"negative: as long as it runs (default: $SITRELAX_LOCK_TIMEOUT "
                             f"or 600)")


def lock_timeout_of(args) -> float | None:
    """`posedb.locking.lock_timeout_of`, loaded when a command runs."""
    from .locking import lock_timeout_of as of

    return of(args)


def _waiting(db: str):
    def report(seconds: float) -> None:
        print_status(f"waiting for another writer of {db} to finish: {seconds:.0f} s")
    return report


def _open(args, create: bool = False):
    """The library of `--db` (a `PoseLibrary`), waiting for other writers as `--lock-timeout`
    says; the notes of its opening (killed writers' copies removed) go to stderr."""
    from .library import PoseLibrary

    lib = PoseLibrary(args.db, create=create, lock_timeout=lock_timeout_of(args),
                      on_wait=_waiting(args.db))
    for note in lib.notes:
        print_event(f"note: {note}")
    lib.notes.clear()
    return lib


def _cmd_import(args) -> int:
    from capture import read_bvh, resolve_path
    from capture.jointmap import read_joint_map

    if args.name and len(args.files) > 1:
        from .schema import LibraryError

        raise LibraryError(f"Expected one file with --name (a name is one take's), got "
                           f"{len(args.files)} files")
    # parsed before the write lock, so other writers wait only for the commit
    parsed = [read_bvh(resolve_path(spec), unit=args.unit) for spec in args.files]
    joint_map = read_joint_map(args.joint_map) if args.joint_map else None
    new = not os.path.exists(args.db)
    lib = _open(args, create=True)
    names = []
    try:
        with lib.edit() as ed:
            for bvh in parsed:
                names.append(ed.import_bvh(bvh, name=args.name, subject=args.subject,
                                           tags=args.tag, notes=args.notes,
                                           joint_map=joint_map))
    except BaseException as exc:
        from .locking import LockedError

        if new and not isinstance(exc, LockedError):  # (another writer has it: theirs now)
            _drop_if_empty(args.db)
        raise
    takes = [lib.take(t).as_dict() for t in names]
    _print(takes, args.json, "\n".join(f"imported {t['name']} ({t['id']}): {t['frames']} frames, "
                                      f"{t['duration']:.2f} s" for t in takes))
    return 0


def _drop_if_empty(db: str) -> None:
    """Removes the library `db` if it holds nothing (no take, so no pose): one an import made
    and failed to fill. Only with its lock free and held meanwhile (a writer that came since
    keeps it), and only with no recording's journal beside it (a recording that started into
    it keeps it; one starting meanwhile makes it again once this lock is released:
    `posedb.record.TakeRecorder`); the lock file stays, as another writer may be waiting on
    it."""
    from .library import PoseLibrary
    from .locking import try_exclusive
    from .record import journal_dir

    lock = try_exclusive(db)
    if lock is None:
        return
    try:
        journals = journal_dir(db)
        if not PoseLibrary(db).takes() and not (journals.is_dir()
                                                and any(journals.glob("*.raw"))):
            os.unlink(db)
    except Exception:  # noqa: BLE001 (unreadable or gone: someone else's business, left alone)
        pass
    finally:
        lock.release()


def _cmd_list(args) -> int:
    from .record import recordings

    lib = _open(args)
    if args.take is not None:  # a name as stored (composed, NFC) unless one is stored as given
        import unicodedata

        given = {t.id for t in lib.takes()} | {t.name for t in lib.takes()} | \
            {r.take for r in recordings(args.db)}
        if args.take not in given:
            args.take = unicodedata.normalize("NFC", args.take)
    rows: list[dict] = []
    if args.kind in (None, "take"):
        rows += [t.as_dict() for t in lib.find_takes(args.tag, subject=args.subject)
                 if args.take is None or args.take in (t.id, t.name)]
    running = [r for r in recordings(args.db) if args.take is None or args.take == r.take]
    names = {t.id: t.name for t in lib.takes()}
    stored = args.take is None or args.take in names or args.take in names.values()
    if args.kind in (None, "pose") and (stored or not running):  # (a take still recording
        # has no poses yet; a take that is neither is an error)
        rows += [p.as_dict(names[p.take]) for p in lib.find_poses(args.tag, take=args.take,
                                                                   subject=args.subject)]
    if args.kind in (None, "recording") and not args.tag:
        rows += [r.as_dict() for r in running]
    if args.json:
        print(_json(rows))
        return 0
    for r in rows:
        tags = " ".join(r.get("tags", []))
        if r["kind"] == "take":
            print(f"take  {r['name']:<32} {r['frames']:>7} frames {r['duration']:>8.2f} s  {tags}")
        elif r["kind"] == "pose":
            print(f"pose  {r['name']:<32} {r['take']}#{r['frame']:<6} "
                  f"[{','.join(r['supports'])}]  {tags}")
        else:
            print(f"rec   {r['name']:<32} {r['state']}")
    return 0


def _cmd_show(args) -> int:
    from .schema import NotFoundError

    lib = _open(args)
    try:
        info = lib.pose(args.name).as_dict(None)
        info["take"] = lib.take(info["take_id"]).name
    except ValueError:
        try:
            info = lib.take(args.name).as_dict()
        except NotFoundError:  # (the name may be either)
            raise NotFoundError(f"No pose or take {args.name!r} in {lib.path}") from None
    shown = dict(info)
    if "placement" in shown:  # (a pose's; None: the standard placement)
        placed = shown["placement"]
        shown["placement"] = "standard" if placed is None else (
            "offset " + ", ".join(f"{x:.4f}" for x in placed["offset_m"]) +
            f" m, heading {placed['heading_rad']:.4f} rad (where its relaxation left it)")
    _print(info, args.json, "\n".join(f"{k:<12} {v}" for k, v in shown.items()))
    return 0


def _cmd_tag(args) -> int:
    lib = _open(args)
    with lib.edit() as ed:
        tags = ed.tag(args.name, add=args.tags if not args.remove else (),
                      remove=args.tags if args.remove else ())
    _print({"name": args.name, "tags": list(tags)}, args.json, f"{args.name}: {' '.join(tags)}")
    return 0


def _cmd_pose_add(args) -> int:
    lib = _open(args)
    pose = lib.add_pose(args.take, args.frame, args.name, tags=args.tag,
                        supports=args.support, notes=args.notes)
    _print(pose.as_dict(lib.take(pose.take).name), args.json,
           f"added pose {pose.name} ({pose.id}) at frame {pose.frame}")
    return 0


def _named(lib, ref: str, kind: str) -> tuple[str, str, str]:
    """(kind, id, name) of what `ref` names as a rename looks for it: a take for `kind`
    "take", else a pose or, failing that, a take (an error naming both when neither)."""
    from .schema import NotFoundError

    if kind != "take":
        try:
            pose = lib.pose(ref)
            return "pose", pose.id, pose.name
        except NotFoundError:
            try:
                lib.take(ref)
            except NotFoundError:
                raise NotFoundError(f"No pose or take {ref!r} in {lib.path}") from None
    take = lib.take(ref)
    return "take", take.id, take.name


def _cmd_pose_rename(args, kind: str = "") -> int:
    """`db pose rename` (a pose, else a take) and `db take rename` (`kind` "take": a take)."""
    lib = _open(args)
    with lib.edit() as ed:
        what, ident, old = _named(lib, args.name, kind)  # (as of the write lock)
        (ed.rename_take if what == "take" else ed.rename)(ident, args.new_name)
    new = (lib.take(ident) if what == "take" else lib.pose(ident)).name
    _print({"kind": what, "id": ident, "name": new, "old_name": old}, args.json,
           f"renamed {kind + ' ' if kind else ''}{args.name} to {args.new_name}")
    return 0


def _cmd_pose_delete(args) -> int:
    lib = _open(args)
    with lib.edit() as ed:
        pose = lib.pose(args.name)  # (as of the write lock)
        ed.delete_pose(pose.id)
    _print({"kind": "pose", "id": pose.id, "name": pose.name, "deleted": True}, args.json,
           f"deleted pose {args.name}")
    return 0


def _cmd_take_delete(args) -> int:
    lib = _open(args)
    with lib.edit() as ed:
        take = lib.take(args.name)  # (as of the write lock)
        poses = [p.name for p in lib.find_poses(take=take.id)]
        ed.delete_take(take.id)
    _print({"kind": "take", "id": take.id, "name": take.name, "deleted": True,
            "poses_deleted": poses}, args.json,
           f"deleted take {take.name} and its {len(poses)} pose(s)")
    return 0


def _cmd_suggest(args) -> int:
    from .suggest import suggest_poses

    lib = _open(args)
    take = lib.take(args.take)
    rows = suggest_poses(lib, take.id, accept=args.accept, tags=args.tag,
                         supports=args.support, max_speed=args.max_speed,
                         min_duration=args.min_duration)
    text = "\n".join(
        f"frames {r['start']}-{r['end']} ({(r['end'] - r['start'] + 1) * take.frame_time:.2f} s):"
        f" propose frame {r['frame']}" + _accepted_text(r) for r in rows) or "no held posture found"
    _print(rows, args.json, text)
    return 0


def _accepted_text(row: dict) -> str:
    """What `db suggest --accept` did with a hold: a new pose, or one it was already."""
    if "pose" not in row:
        return ""
    if not row.get("added", True):
        return f" -> already pose {row['name']}, skipped"
    return f" -> pose {row['name']} (tags: {' '.join(row['tags']) or '-'})"


def _cmd_export(args) -> int:
    from capture import write_bvh

    lib = _open(args)
    take = lib.take(args.name)
    end = take.frames - 1 if args.end is None else args.end
    if not 0 <= args.start <= end <= take.frames - 1:
        from .schema import LibraryError

        raise LibraryError(f"Expected --start and --end (both inclusive) within 0..{take.frames - 1} "
                           f"of take {take.name!r}, start <= end, got {args.start}..{end}")
    bvh = lib.take_bvh(take.id, args.start, end + 1)
    write_bvh(args.out, bvh.skeleton, bvh.motion)
    _print({"kind": "take", "id": take.id, "name": take.name, "path": str(args.out),
            "start": args.start, "end": end, "frames": bvh.motion.num_frames}, args.json,
           f"wrote {bvh.motion.num_frames} frame{'' if bvh.motion.num_frames == 1 else 's'} "
           f"of {take.name} to {args.out}")
    return 0


def _cmd_check(args) -> int:
    from .verify import verify

    problems = verify(args.db, full=not args.quick)  # without opening: it may not open
    status = 1 if problems else 0  # (the JSON says it, as an error's JSON says its 2)
    _print({"path": args.db, "ok": not problems, "problems": problems, "exit_status": status},
           args.json, "\n".join(problems) or f"{args.db}: no problem found")
    return status


def _cmd_compact(args) -> int:
    sizes = _open(args).compact()
    _print(sizes, args.json, f"compacted {sizes['path']}: {sizes['size_before'] / 1e6:.2f} MB "
                             f"-> {sizes['size_after'] / 1e6:.2f} MB")
    return 0


def _cmd_recover(args) -> int:
    from .record import AS_RECORDED, recover

    avatar = None if args.every_avatar else AS_RECORDED if args.avatar is None else args.avatar
    rows = recover(args.db, journal=args.journal, avatar=avatar,
                   lock_timeout=lock_timeout_of(args), on_wait=_waiting(args.db))
    _print(rows, args.json, "\n".join(
        f"{r['take']}: {r['status']}" + (f" (its journal {r['journal']} is kept)"
                                         if r["status"].startswith("failed") else "")
        for r in rows) or "nothing to recover")
    return 1 if any(r["status"].startswith("failed") for r in rows) else 0


def _cmd_stats(args) -> int:
    from .record import recordings

    stats = _open(args).stats()
    stats["recordings"] = [r.as_dict() for r in recordings(args.db)]
    _print(stats, args.json, "\n".join(f"{k:<15} {v}" for k, v in stats.items()
                                      if k != "recordings"))
    return 0


def _cmd_record(args) -> int:
    from .record import record

    stopping = {"flag": False}
    previous = signal.signal(signal.SIGINT, lambda s, f: stopping.__setitem__("flag", True))

    from capture.avatars import AvatarNotSeenError
    from capture.cli import avatar_not_seen, avatars_text

    from .record import journal_dir

    existed = os.path.exists(args.db)

    def nothing_made() -> None:
        """A recording that stored nothing leaves nothing: not even the empty library (and
        journal folder) this command made."""
        if existed:
            return
        _drop_if_empty(args.db)
        try:
            journal_dir(args.db).rmdir()
        except OSError:
            pass  # (not empty, or gone: left as it is)

    def progress(s: dict) -> None:
        fps = f"{s['fps']:.1f}" if s["fps"] else "-"
        who = f"  avatars {avatars_text(s['avatars'])}" if s.get("avatars") else ""
        print_status(f"recording {args.take}: {s['frames']} frames  fps {fps}  dropped "
                     f"{s['dropped']}  corrupt {s['corrupt']}{who}")

    try:
        summary = record(args.source, args.db, args.take, args.skeleton, duration=args.duration,
                         frames=args.frames, subject=args.subject, tags=args.tag,
                         notes=args.notes, unit=args.unit, avatar=args.avatar,
                         on_event=print_event, on_progress=progress,
                         stop=lambda: stopping["flag"], lock_timeout=lock_timeout_of(args))
    except AvatarNotSeenError as exc:
        nothing_made()
        return avatar_not_seen(exc, args.json)
    finally:
        signal.signal(signal.SIGINT, previous)
    take = summary["take"]
    if not take:
        text = "no frame received; no take stored"
    elif len(summary["takes"]) == 1:
        text = (f"recorded {summary['frames']} frames ({summary['dropped']} dropped, "
                f"{summary['corrupt']} corrupt) into take {take['name']}")
    else:
        text = (f"recorded {len(summary['takes'])} avatars, each into a take of its own "
                f"({summary['corrupt']} corrupt frames on the stream):")
    for a in summary["avatars"] if take else ():
        if len(summary["avatars"]) > 1 or summary.get("avatar") is not None:
            where = f"-> take {a['take']}" if a.get("take") else "not kept"
            text += (f"\n  {a['name'] or '(no name)'} (index {a['index']}): {a['frames']} "
                     f"frames, {a['dropped'] or 0} dropped  {where}")
    _print(summary, args.json, text)
    if take:
        return 0
    nothing_made()
    from capture.cli import no_frame_reason

    print(f"sitrelax: error: no frame received from {args.source} "
          f"({no_frame_reason(summary)})", file=sys.stderr)
    return 2


def register(subparsers, groups: dict) -> None:
    """Adds `db` and `capture record` to the top-level parser."""
    db = subparsers.add_parser("db", help="the pose library: takes, poses, tags")
    sub = db.add_subparsers(dest="db_command", required=True)
    _register_take_commands(sub)
    _register_pose_commands(sub)
    _register_library_commands(sub)
    _register_record(groups["capture"])


def _library_options(p):
    """The options every library command takes: `--db`, `--lock-timeout` and `--json`."""
    p.add_argument("--db", default=DEFAULT_DB,
                   help=f"the pose library file (default: $SITRELAX_DB or {DEFAULT_DB})")
    add_lock_timeout_option(p)
    p.add_argument("--json", action="store_true", help="machine-readable output")
    return p


def _register_take_commands(sub) -> None:
    """`db import`, `db list`, `db show` and `db tag`."""
    p = _library_options(sub.add_parser("import", help="import BVH files as takes"))
    p.add_argument("files", nargs="+", help=".bvh paths or bundled:NAME")
    p.add_argument("--name", help="take name (one file only; default: the file name)")
    p.add_argument("--subject", default="", help="who was recorded")
    p.add_argument("--tag", action="append", default=[], help="a tag (repeatable)")
    p.add_argument("--notes", default="")
    p.add_argument("--unit", default="auto", help="length unit of the files (default: auto)")
    p.add_argument("--joint-map", default=None, help="joint-map file (TOML, role = \"joint\") "
                   "stored with the skeleton, for one no profile knows")
    p.set_defaults(func=_cmd_import)

    p = _library_options(sub.add_parser("list", help="list takes, poses and recordings"))
    p.add_argument("--tag", help="tag expression, e.g. 'sit and not floor'")
    p.add_argument("--take", help="only this take (name or id), its poses and its recording "
                   "while it records")
    p.add_argument("--subject", help="only this subject")
    p.add_argument("--kind", choices=("take", "pose", "recording"))
    p.set_defaults(func=_cmd_list)

    p = _library_options(sub.add_parser("show", help="show a take or pose"))
    p.add_argument("name")
    p.set_defaults(func=_cmd_show)

    p = _library_options(sub.add_parser("tag", help="add (or with --remove, remove) tags"))
    p.add_argument("name", help="pose or take")
    p.add_argument("tags", nargs="+")
    p.add_argument("--remove", action="store_true")
    p.set_defaults(func=_cmd_tag)


def _support_option(p, what: str) -> None:
    p.add_argument("--support", nargs="+", default=[DEFAULT_SUPPORT], choices=SUPPORT_NAMES,
                   metavar="NAME",
                   help=f"{what}: regions ({' '.join(BODY_REGIONS)}), parts "
                        f"({' '.join(SUPPORT_GROUPS)}) or a use ({' '.join(SUPPORT_USES)}); "
                        f"default {DEFAULT_SUPPORT}")


def _register_pose_commands(sub) -> None:
    """`db pose add|rename|delete` and `db suggest`."""
    pose = sub.add_parser("pose", help="add, rename or delete poses")
    psub = pose.add_subparsers(dest="pose_command", required=True)
    p = _library_options(psub.add_parser("add", help="name a frame of a take as a pose"))
    p.add_argument("take")
    p.add_argument("frame", type=int, help="0-based frame of the take")
    p.add_argument("--name", required=True)
    p.add_argument("--tag", action="append", default=[])
    _support_option(p, "the body regions the pose needs supported")
    p.add_argument("--notes", default="")
    p.set_defaults(func=_cmd_pose_add)
    p = _library_options(psub.add_parser("rename", help="rename a pose (or a take)"))
    p.add_argument("name")
    p.add_argument("new_name")
    p.set_defaults(func=_cmd_pose_rename)
    p = _library_options(psub.add_parser("delete", help="delete a pose (its take stays)"))
    p.add_argument("name")
    p.set_defaults(func=_cmd_pose_delete)

    take = sub.add_parser("take", help="rename or delete takes")
    tsub = take.add_subparsers(dest="take_command", required=True)
    p = _library_options(tsub.add_parser("rename", help="rename a take"))
    p.add_argument("name")
    p.add_argument("new_name")
    p.set_defaults(func=lambda a: _cmd_pose_rename(a, "take"))
    p = _library_options(tsub.add_parser("delete", help="delete a take and the poses made from it "
                                                        "(`db compact` then frees the space)"))
    p.add_argument("name")
    p.set_defaults(func=_cmd_take_delete)

    p = _library_options(sub.add_parser("suggest", help="propose poses where the body holds still"))
    p.add_argument("take")
    p.add_argument("--accept", action="store_true", help="store the proposals as poses")
    p.add_argument("--tag", action="append", default=[], help="tags for accepted poses")
    _support_option(p, "the body regions accepted poses need supported")
    p.add_argument("--max-speed", type=number(0, low_open=True), default=DEFAULT_MAX_SPEED,
                   help=f"stillness threshold, m/s > 0 (default {DEFAULT_MAX_SPEED})")
    p.add_argument("--min-duration", type=number(0, MAX_HOLD_DURATION),
                   default=DEFAULT_MIN_DURATION,
                   help=f"shortest held posture, s, 0 to {MAX_HOLD_DURATION:g} (default "
                        f"{DEFAULT_MIN_DURATION})")
    p.set_defaults(func=_cmd_suggest)


def _register_library_commands(sub) -> None:
    """`db export`, `db recover`, `db stats`, `db check` and `db compact`: the library as a
    whole."""
    p = _library_options(sub.add_parser("export", help="write a take (or a frame range) as BVH"))
    p.add_argument("name")
    p.add_argument("--out", required=True)
    p.add_argument("--start", type=int, default=0, help="first frame (0-based)")
    p.add_argument("--end", type=int, default=None, help="last frame, inclusive")
    p.set_defaults(func=_cmd_export)

    p = _library_options(sub.add_parser(
        "recover", help="turn interrupted recordings into takes",
        description="Stores the journals that interrupted recordings left as takes, as their "
                    "recorders would have. A recording made with --avatar of which no frame "
                    "came is refused and kept, naming the avatars that came: --journal with "
                    "--avatar or --every-avatar stores it."))
    p.add_argument("--journal", metavar="PATH", default=None,
                   help="recover this journal only (as `db recover` and `db stats` name it)")
    who = p.add_mutually_exclusive_group()
    who.add_argument("--avatar", metavar="NAME_OR_INDEX", default=None,
                     help="with --journal: keep this avatar (its name, or its index: digits "
                          "are an index) instead of the one chosen when it was recorded")
    who.add_argument("--every-avatar", action="store_true",
                     help="with --journal: keep every avatar, each as a take of its own when "
                          "several came, instead of the one chosen when it was recorded")
    p.set_defaults(func=_cmd_recover)

    p = _library_options(sub.add_parser("stats", help="what the library holds"))
    p.set_defaults(func=_cmd_stats)

    p = _library_options(sub.add_parser("check", help="verify the library (exit 1 if damaged)"))
    p.add_argument("--quick", action="store_true",
                   help="metadata and pose table only, not every chunk of every take")
    p.set_defaults(func=_cmd_check)

    p = _library_options(sub.add_parser(
        "compact", help="rewrite the library without the bytes of deleted takes and poses"))
    p.set_defaults(func=_cmd_compact)


def _register_record(capture_sub) -> None:
    """`capture record`, added to the `capture` group that `capture.cli` made."""
    rec = capture_sub.add_parser(
        "record", help="record a stream into a new take (one per avatar)",
        description="Records a stream into a new take. When several people wear suits, Axis "
                    "sends one frame per avatar; avatars are never mixed: without --avatar "
                    "every avatar is kept, and when several come each becomes its own take, "
                    "named TAKE-AVATARNAME (TAKE when only one came); with --avatar only that "
                    "avatar is kept, in TAKE. The progress line and --json name every avatar "
                    "seen with its frame count.")
    rec.add_argument("source", help="stream source URL (see `capture listen`)")
    _library_options(rec)
    rec.add_argument("--take", required=True, help="name of the new take")
    rec.add_argument("--skeleton", required=True, help="the BVH header paired with the stream")
    rec.add_argument("--duration", type=number(0, low_open=True), default=None,
                     help="seconds to record, > 0 (default: until Ctrl-C or the source ends)")
    rec.add_argument("--frames", type=number(1, whole=True), default=None,
                     help="frames of one avatar to record, at least 1: stops once the kept "
                          "avatar (without --avatar, any avatar) has that many (default: no "
                          "limit)")
    rec.add_argument("--subject", default="")
    rec.add_argument("--tag", action="append", default=[])
    rec.add_argument("--notes", default="")
    rec.add_argument("--unit", default="auto", help="length unit of the skeleton header")
    rec.add_argument("--avatar", metavar="NAME_OR_INDEX", default=None,
                     help="keep only this avatar (its name, e.g. Avatar01, or its index: "
                          "digits are an index), in "
                          "the take --take; an avatar that never comes is an error naming "
                          "those that did, and nothing is stored (default: every avatar, each "
                          "as its own take TAKE-AVATARNAME when several come)")
    rec.set_defaults(func=_cmd_record)
