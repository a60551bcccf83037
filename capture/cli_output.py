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


def _bound(value: float) -> str:
    """A bound as a reader types it: whole numbers in full (4294967295, not 4.29497e+09)."""
    return str(int(value)) if float(value).is_integer() else f"{value:g}"


def check_limits(duration, frames, error: type[Exception] = ValueError) -> None:
    """Refuses limits that could not end a reading or a recording as meant (an `error` naming
    the limit): a duration not a finite number of seconds > 0 (NaN never ends one), frames
    not a whole number >= 1 (0 or fewer would end it before its first frame)."""
    import math

    import numpy as np

    if duration is not None:
        try:
            seconds = float(duration)
        except (TypeError, ValueError):
            seconds = math.nan
        if not (math.isfinite(seconds) and seconds > 0):
            raise error(f"Expected a duration in seconds > 0, got {duration!r}")
    if frames is not None:
        whole = isinstance(frames, (int, np.integer)) and not isinstance(frames, bool)
        if not whole or frames < 1:
            raise error(f"Expected a whole number of frames >= 1, got {frames!r}")


def number(low: float | None = None, high: float | None = None, *, whole: bool = False,
           low_open: bool = False):
    """An argparse `type` for a finite number (a whole one with `whole`) within [low, high]
    (`low_open`: above `low`): the option's error names what it expected and what it got
    (argparse prints it with the option's name and exits with status 2)."""
    import argparse
    import math

    def parse(text: str):
        noun = "a whole number" if whole else "a number"
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {noun}, got {text!r}") from None
        if not math.isfinite(value) or (whole and not value.is_integer()):
            raise argparse.ArgumentTypeError(f"expected {noun}, got {text!r}")
        if low is not None and (value <= low if low_open else value < low):
            raise argparse.ArgumentTypeError(
                f"expected {noun} {'>' if low_open else '>='} {_bound(low)}, got {text!r}")
        if high is not None and value > high:
            raise argparse.ArgumentTypeError(f"expected {noun} <= {_bound(high)}, got {text!r}")
        return int(value) if whole else value

    parse.__name__ = "whole number" if whole else "number"  # (argparse's fallback message)
    return parse
