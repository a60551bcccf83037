"""Cross-platform file locks for the pose library and its recordings' journals.

One writer at a time, readers never blocked (they take no lock), and a killed writer leaves no
stale lock. `filelock.FileLock` takes an operating-system lock (flock on POSIX, msvcrt on
Windows) that the system drops when its holder dies. Where neither exists it falls back to a
lock file naming the holder's pid and host, which the next writer breaks once that process is
gone. That fallback lives at `<file>.softlock` rather than `<file>.lock`, because an OS lock
leaves its (empty) file in place and the fallback would read that file as held.

Paths are derived with `pathlib` alone, the same way on every platform: the lock of
`<dir>/<name>` is `<dir>/<name>.lock`.
"""

from __future__ import annotations

import math
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

import filelock

from .schema import LibraryError

WAIT_REPORT_EVERY = 1.0  # s between on_wait calls while waiting for another writer


class LockedError(LibraryError):
    """Another process holds the library's write lock for too long."""


def has_os_lock() -> bool:
    """Whether this platform has a lock its system releases when the holder dies."""
    return sys.platform == "win32" or bool(filelock.has_fcntl)


def lock_path(path: str | Path) -> Path:
    """The lock file guarding `path`."""
    path = Path(path)
    return path.with_name(path.name + (".lock" if has_os_lock() else ".softlock"))


def _new_lock(path: Path) -> filelock.BaseFileLock:
    # mode 0o666 (less the umask): every user who may write the library may take its lock
    return filelock.FileLock(str(lock_path(path)), mode=0o666, thread_local=False)


@contextmanager
def exclusive(path: str | Path, *, timeout: float | None,
              on_wait: Callable[[float], None] | None = None,
              what: str = "The pose library") -> Iterator[None]:
    """Holds the write lock of `path`, waiting up to `timeout` seconds (None: as long as the
    holder lives, as does a negative or infinite one) and calling `on_wait(seconds waited)`
    about once a second meanwhile."""
    timeout = lock_wait(timeout)
    folder = Path(path).parent
    if not folder.is_dir():  # (the lock would make it: a mistyped path's folders)
        raise LibraryError(f"{what} {path}: its folder {folder} does not exist")
    lock = _new_lock(Path(path))
    start = time.monotonic()
    while True:
        waited = time.monotonic() - start
        step = WAIT_REPORT_EVERY if timeout is None else min(WAIT_REPORT_EVERY,
                                                              max(0.0, timeout - waited))
        try:
            lock.acquire(timeout=step, poll_interval=0.05)
            break
        except filelock.Timeout:
            waited = time.monotonic() - start
            if timeout is not None and waited >= timeout:
                raise LockedError(f"{what} {path} is locked by another writer (waited "
                                  f"{waited:.0f} s; set --lock-timeout or "
                                  "$SITRELAX_LOCK_TIMEOUT to wait longer)") from None
            if on_wait is not None:
                on_wait(waited)
    try:
        yield
    finally:
        lock.release()


def lock_wait(seconds: float | None, what: str = "a lock timeout") -> float | None:
    """Seconds to wait for another writer, None for as long as it lives (None, a negative or
    an infinite number); a LibraryError for a number that is not one (NaN)."""
    if seconds is None:
        return None
    seconds = float(seconds)
    if math.isnan(seconds):
        raise LibraryError(f"Expected {what} in seconds (negative: wait as long as the other "
                           f"writer runs), got nan")
    return None if seconds < 0 or math.isinf(seconds) else seconds


def try_exclusive(path: str | Path) -> filelock.BaseFileLock | None:
    """The write lock of `path` if it is free right now (release it when done), else None;
    None too where the lock file cannot be made (a read-only folder)."""
    lock = _new_lock(Path(path))
    try:
        lock.acquire(timeout=0)
    except (filelock.Timeout, OSError):
        return None
    return lock



def lock_timeout_of(args) -> float | None:
    """The seconds a command's `--lock-timeout` waits (`add_lock_timeout_option`): the
    library's default when not given, None for as long as the other writer runs."""
    value = getattr(args, "lock_timeout", None)
    if value is None:
        from .library import default_lock_timeout

        return default_lock_timeout()
    return lock_wait(value, "--lock-timeout")
