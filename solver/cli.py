"""The `sitrelax` command: composes each package's subcommands."""

from __future__ import annotations

import argparse
import json
import sys

from capture import cli as capture_cli
from posedb import cli as posedb_cli

from .bench import format_table, run_benchmarks


def _cmd_bench(args: argparse.Namespace) -> int:
    def progress(msg: str) -> None:
        print(f"bench {msg}", file=sys.stderr, flush=True)

    rows = run_benchmarks(args.names, repeats=args.repeats, progress=progress)
    print(json.dumps(rows, indent=2) if args.json else format_table(rows))
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sitrelax",
        description="Turn motion-captured poses into furniture surfaces that support them.",
    )
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", required=True)
    groups = capture_cli.register(sub)
    posedb_cli.register(sub, groups)
    bench = sub.add_parser("bench", help="run the benchmarks (medians, speed-ups)")
    bench.add_argument("names", nargs="*", help="entries to run (default: all)")
    bench.add_argument("--repeats", type=int, default=None,
                       help="timed runs per entry (default: per entry)")
    bench.add_argument("--json", action="store_true", help="machine-readable output")
    bench.set_defaults(func=_cmd_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("sitrelax: interrupted", file=sys.stderr)
        return 130
    except (ValueError, OSError, KeyError) as exc:
        if args.debug:
            raise
        if isinstance(exc, KeyError) and exc.args:
            message = exc.args[0]
        elif isinstance(exc, OSError) and exc.filename is not None and exc.strerror:
            message = f"{exc.strerror}: {exc.filename}"
        else:
            message = exc
        print(f"sitrelax: error: {message}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
