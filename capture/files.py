"""Files written whole or not at all: a temporary file in the same folder, then a rename; and
results folders that a command which fails before writing into them does not leave behind."""

from __future__ import annotations

import errno
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator


def write_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Writes bytes to `path` through a temporary file in the same folder and a rename; an
    error names `path` (or its missing folder), never the temporary file."""
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(errno.EISDIR, "Expected a file name, got a folder", str(path))
    if not path.parent.is_dir():  # (a bare name's parent is ".")
        raise FileNotFoundError(errno.ENOENT, "No such folder to write into", str(path.parent))
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    umask = os.umask(0)
    os.umask(umask)
    try:
        os.fchmod(fd, 0o666 & ~umask)  # as an ordinary new file, not mkstemp's 0600
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


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
