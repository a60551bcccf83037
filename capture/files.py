"""Files written whole or not at all: a temporary file in the same folder, then a rename; and
results folders that a command which fails before writing into them does not leave behind."""

from __future__ import annotations

import errno
import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterable, Iterator

STAGE_PREFIX = ".sitrelax-writing-"  # a results folder's hidden folder of the results to come


def write_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Writes bytes to `path` through a temporary file in the same folder and a rename; an
    error names `path` (or its missing folder), never the temporary file."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(errno.EISDIR, "Expected a file name, got a folder", str(path))
    if not path.parent.is_dir():  # (a bare name's parent is ".")
        raise FileNotFoundError(errno.ENOENT, "No such folder to write into", str(path.parent))
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:  # (a folder this may not write into)
        raise _naming(exc, path) from None
    umask = os.umask(0)
    os.umask(umask)
    try:
        os.fchmod(fd, 0o666 & ~umask)  # as an ordinary new file, not mkstemp's 0600
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        if isinstance(exc, OSError):  # (a full disk says so without a file name)
            raise _naming(exc, path) from None
        raise


def _naming(exc: OSError, path: Path) -> OSError:
    """The error `exc` naming `path` (the file the caller asked for) as its file."""
    return OSError(exc.errno, exc.strerror or str(exc), str(path))


@contextmanager
def made_folder(path: str | os.PathLike) -> Iterator[Path]:
    """Makes the folder `path` (and its parents) for a command's results; when the block
    raises before anything was written into the folders it made, they go again (a failed
    command leaves no empty results folder behind, nor the empty parents made for it)."""
    folder = Path(path)
    made = []  # the folders this makes, the deepest first
    for f in (folder, *folder.parents):
        if f.exists():
            break
        made.append(f)
    folder.mkdir(parents=True, exist_ok=True)
    try:
        yield folder
    except BaseException:
        for f in made:
            try:
                f.rmdir()  # (only when empty)
            except OSError:
                break
        raise


@contextmanager
def results_folder(path: str | os.PathLike,
                   previous: Callable[[Path], Iterable[str]] | None = None,
                   last: str | None = None) -> Iterator[Path]:
    """A command's results folder `path`, written whole or not at all.

    The block writes into a hidden folder inside `path` (yielded). When it ends well, its
    files take the places of those of the same names (`last`, the file a reader trusts, such
    as report.json, the last of them) and the files an earlier result left that `previous`
    (called with the folder, before) names and this one did not write go: a folder written
    again holds one result, not two mixed. When the block raises, or is interrupted, the
    folder is as it was (and gone again if this made it, `made_folder`). An error that names
    a file of the hidden folder names it in `path`. A hidden folder left by a run that was
    killed (its process gone) goes when the next run starts."""
    if not os.fspath(path).strip():
        raise ValueError("Expected a results folder, got an empty name")
    with made_folder(path) as folder:
        _drop_orphans(folder)
        stale = set(previous(folder)) if previous is not None else set()
        try:
            stage = Path(tempfile.mkdtemp(prefix=f"{STAGE_PREFIX}{os.getpid()}-", dir=folder))
        except OSError as exc:  # (checked before any work is done)
            raise OSError(exc.errno, f"Cannot write the results into this folder "
                                     f"({exc.strerror or exc})", str(folder)) from None
        try:
            try:
                yield stage
            except OSError as exc:
                if exc.filename is None or not str(exc.filename).startswith(str(stage)):
                    raise
                named = folder / Path(exc.filename).relative_to(stage)
                raise OSError(exc.errno, exc.strerror or str(exc), str(named)) from None
            replace_results(stage, folder, stale, last)
        finally:
            shutil.rmtree(stage, ignore_errors=True)


def replace_results(stage: Path, folder: Path, stale: Iterable[str] = (),
                    last: str | None = None) -> None:
    """Moves every file of `stage` into `folder`, in place of the file of the same name, `last`
    the last; then removes the files of `folder` named in `stale` (an earlier result's) that
    `stage` did not hold and that nobody changed since that result was written (none newer
    than its `last`, written after them: a file the user edited stays). Should a move fail or
    be interrupted, every file moved so far goes back where it was, in `stage` or in
    `folder` (and the error is raised); `stale` is then left alone. Only plain names of files
    are removed (no folder, nothing outside `folder`)."""
    made = sorted((p for p in stage.iterdir() if p.is_file()),
                  key=lambda p: (p.name == last, p.name))
    written_until = _mtime(folder / last) if last is not None else None
    for path in made:  # (a folder of the user's is never moved aside, nor lost with it)
        if (folder / path.name).is_dir() and not (folder / path.name).is_symlink():
            raise IsADirectoryError(errno.EISDIR, "Expected a file name, got a folder",
                                    str(folder / path.name))
    with _interrupt_deferred():  # (moving in or back is never cut short half-way)
        backup = Path(tempfile.mkdtemp(prefix=f"{STAGE_PREFIX}{os.getpid()}-old-",
                                       dir=folder))
        done = []  # the names moved (folder's own file of that name, if any, now in backup)
        try:
            for path in made:
                if os.path.lexists(folder / path.name):
                    os.replace(folder / path.name, backup / path.name)
                done.append(path.name)
                os.replace(path, folder / path.name)
        except BaseException:
            for name in reversed(done):
                if not (stage / name).exists() and os.path.lexists(folder / name):
                    os.replace(folder / name, stage / name)
                if os.path.lexists(backup / name):
                    os.replace(backup / name, folder / name)
            raise
        finally:
            shutil.rmtree(backup, ignore_errors=True)
    written = {p.name for p in made}
    for name in set(stale) - written:
        old = folder / name
        if name == Path(name).name and not name.startswith(".") and old.is_file() and \
                (written_until is None or _mtime(old) <= written_until):
            old.unlink(missing_ok=True)


def _mtime(path: Path) -> float | None:
    """When `path` was last written (None when there is no such file)."""
    try:
        return path.stat().st_mtime
    except OSError:
        return None


@contextmanager
def sigint_handled(handler) -> Iterator[None]:
    """SIGINT (Ctrl-C) handled by `handler` (a function, or `signal.SIG_IGN`) while the block
    runs, then as it was; from the main thread only (elsewhere the block runs as it is).
    Processes started in the block with SIGINT ignored keep it ignored (Python leaves an
    ignored SIGINT ignored)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, before)


@contextmanager
def _interrupt_deferred() -> Iterator[None]:
    """Ctrl-C held back while the block runs and raised as KeyboardInterrupt once it has
    ended (`sigint_handled`)."""
    caught = []
    with sigint_handled(lambda signum, frame: caught.append(signum)):
        yield
    if caught:
        raise KeyboardInterrupt


def _drop_orphans(folder: Path) -> None:
    """Removes the hidden folders of results that runs since killed left in `folder` (their
    names carry their process id; one whose process still runs is left alone)."""
    for stage in folder.glob(f"{STAGE_PREFIX}*"):
        pid = stage.name[len(STAGE_PREFIX):].split("-", 1)[0]
        if not pid.isdigit() or not stage.is_dir():
            continue
        try:
            os.kill(int(pid), 0)
            continue  # (still running: another run writing here)
        except ProcessLookupError:
            pass
        except (PermissionError, OverflowError, OSError):
            continue
        shutil.rmtree(stage, ignore_errors=True)
