"""Human-readable output of the command-line tools, shared by every package's `cli.py`.

Both helpers write to stderr so that stdout stays for results (and `--json`); on a terminal a
status line is rewritten in place and an event first clears it.
"""

from __future__ import annotations

import sys


def print_status(line: str, final: bool = False) -> None:
    """Writes a progress line on stderr, rewritten in place on a terminal.

    line : the whole status text, without a line end.
    final : ends the line on a terminal, so that later output starts below it.
    """
    if sys.stderr.isatty():
        sys.stderr.write("\r" + line + ("\n" if final else ""))
    else:
        sys.stderr.write(line + "\n")
    sys.stderr.flush()


def print_event(message: str) -> None:
    """Writes a one-line event (a connection, a gap) on stderr, clearing a status line first.

    Fits the `on_event` callbacks of `capture.Source`, `capture.Replay` and `posedb.record`.
    """
    if sys.stderr.isatty():
        sys.stderr.write("\r\033[K")
    print(message, file=sys.stderr, flush=True)
