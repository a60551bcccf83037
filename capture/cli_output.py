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
