"""The library's file handling: copies that replace the file in one rename, keeping its owner,
mode and symbolic link, and the removal of copies a killed writer left behind.

A change is written to `.<name>.<pid>-<random>.tmp` beside the library's real file (the target
of a symbolic link, so the link stays a link), given the file's mode, owner and group, forced to
disk and renamed over the file. Only the writer holding the library's lock makes such copies, so
any other one found while holding the lock is left over from a killed writer.
"""

from __future__ import annotations

import logging
import os
import re
import stat
import uuid
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from .schema import LibraryError

log = logging.getLogger("posedb")


class ReadOnlyError(LibraryError):
    """A library this user may not (or should not) change."""


def real_file(path: Path) -> Path:
    """The file a library path names: symbolic links followed, made absolute."""
    return Path(os.path.realpath(path))


def temporary_path(target: Path) -> Path:
    return target.with_name(f".{target.name}.{os.getpid()}-{uuid.uuid4().hex[:8]}.tmp")


def _temporary_form(target: Path) -> re.Pattern:
    """The names `temporary_path` gives copies of `target`, and no other: a copy of a library
    whose name merely starts with this one's (`poses.h5.old` beside `poses.h5`) is not one."""
    return re.compile(re.escape(f".{target.name}.") + r"[0-9]+-[0-9a-f]{8}\.tmp")


def stale_temporaries(target: Path) -> list[Path]:
    """Copies of `target` left by writers that died (call only while holding its lock)."""
    form = _temporary_form(target)
    try:
        names = os.listdir(target.parent)
    except OSError:
        return []
    return sorted(target.parent / n for n in names if form.fullmatch(n))


def remove_stale_temporaries(target: Path) -> list[str]:
    """Removes what `stale_temporaries` finds; returns a note per file removed."""
    notes = []
    for tmp in stale_temporaries(target):
        try:
            size = tmp.stat().st_size
            tmp.unlink()
        except OSError:
            continue
        note = (f"removed {tmp.name} ({size / 1e6:.1f} MB), a copy of {target} left by an "
                "interrupted change")
        log.warning(note)
        notes.append(note)
    return notes


def _describe(st: os.stat_result) -> str:
    owner = str(st.st_uid)
    try:
        import pwd

        owner = pwd.getpwuid(st.st_uid).pw_name
    except (ImportError, KeyError):
        pass
    return f"mode {stat.S_IMODE(st.st_mode):04o}, owner {owner}"


def check_writable(target: Path) -> None:
    """Refuses a library that has no write permission at all (read-only on purpose, even for
    root) or that this user may not write, and a folder where its copy cannot be made."""
    st = target.stat()
    if not st.st_mode & 0o222 or not os.access(target, os.W_OK):
        raise ReadOnlyError(f"{target} is read-only for you ({_describe(st)}): nothing was "
                            "changed; make it writable (chmod u+w) or work on a copy")
    if not os.access(target.parent, os.W_OK | os.X_OK):
        raise ReadOnlyError(f"{target} cannot be changed: its folder {target.parent} is not "
                            "writable (every change writes a new copy beside the file)")


def _take_on_ownership(tmp: Path, target: Path) -> None:
    """Gives the copy the original's mode and, as far as the system allows, owner and group."""
    st = target.stat()
    os.chmod(tmp, stat.S_IMODE(st.st_mode))
    if not hasattr(os, "chown"):
        return
    mine = tmp.stat()
    if (mine.st_uid, mine.st_gid) == (st.st_uid, st.st_gid):
        return
    for uid in (st.st_uid, -1):
        try:
            os.chown(tmp, uid, st.st_gid)
            break
        except PermissionError:
            continue
    if tmp.stat().st_uid != st.st_uid:
        log.warning("%s now belongs to you: only its owner or root can keep its owner "
                    "(uid %d) across a change", target, st.st_uid)


@contextmanager
def replacing(target: Path) -> Iterator[Path]:
    """A temporary file that replaces `target` in one rename when the block succeeds (with
    target's mode and owner when it exists), and is removed when it fails."""
    tmp = temporary_path(target)
    try:
        yield tmp
        if target.exists():
            _take_on_ownership(tmp, target)
        fsync_path(tmp)
        os.replace(tmp, target)
        fsync_dir(target.parent)
    except BaseException:
        unlink(tmp)
        raise


def copy_file(src: Path, dst: Path) -> None:
    """Copies a file, in the kernel (or as a reflink where the filesystem shares blocks) where
    the platform offers `os.copy_file_range`, else by blocks."""
    with open(src, "rb") as fin, open(dst, "wb") as fout:
        size = os.fstat(fin.fileno()).st_size
        copied = 0
        try:
            while copied < size:
                n = os.copy_file_range(fin.fileno(), fout.fileno(), size - copied)
                if n == 0:
                    break
                copied += n
        except (OSError, AttributeError):
            fin.seek(copied)
            fout.seek(copied)
            while chunk := fin.read(1 << 20):
                fout.write(chunk)


def fsync_path(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_dir(path: Path) -> None:
    """Forces a rename to disk; a no-op where folders cannot be opened (Windows)."""
    try:
        fd = os.open(path or ".", os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def unlink(path: Path) -> None:
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass
