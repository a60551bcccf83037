"""`sitrelax bvh ...`: command-line access to BVH recordings."""

from __future__ import annotations

import argparse
import json
import math
import signal
import time

# numpy and the readers load when a command runs: `sitrelax --help` stays fast
from .cli_output import check_limits, number, print_event, print_status
from .recordings import bundled_recordings, resolve_path


def bvh_info(spec: str, unit: str = "auto") -> dict:
    """A summary of a BVH file (`spec` is a path or `bundled:NAME`) as plain data."""
    import numpy as np

    from .bvh import read_bvh

    path = resolve_path(spec)
    bvh = read_bvh(path, unit=unit)
    sk, mo = bvh.skeleton, bvh.motion
    info = {
        "file": str(path),
        "joints": sk.num_joints,
        "frames": mo.num_frames,
        "frame_time": mo.frame_time,
        "fps": mo.fps,
        "channels": sk.num_channels,
        "duration": mo.duration,
        "joint_names": list(sk.names),
        "profile": bvh.profile,
        "unit_m": sk.unit_m,
        "root_height_min_m": None,
        "root_height_max_m": None,
    }
    if sk.unit_m is not None and mo.num_frames:
        heights = sk.root_positions(mo.channels)[:, 1]
        info["root_height_min_m"] = float(np.min(heights))
        info["root_height_max_m"] = float(np.max(heights))
    return info


def _json_safe(value):
    """`value` with every non-finite float as None: JSON has no NaN or Infinity."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    return value


def _cmd_info(args: argparse.Namespace) -> int:
    info = bvh_info(args.file, args.unit)
    if args.json:
        # The reader bounds the frame time, so fps is finite; the guard keeps the output valid
        # JSON whatever a future field holds.
        print(json.dumps(_json_safe(info), indent=2, allow_nan=False))
        return 0
    print(f"file        {info['file']}")
    print(f"profile     {info['profile'] or 'unknown'}")
    print(f"joints      {info['joints']}")
    print(f"channels    {info['channels']}")
    print(f"frames      {info['frames']} at {info['frame_time']:g} s ({info['fps']:.1f} fps)")
    print(f"duration    {info['duration']:.3f} s")
    if info["unit_m"] is None:
        print("unit        unknown (pass --unit, e.g. --unit cm, for metric heights)")
    else:
        print(f"unit        {info['unit_m']:g} m per file unit")
        if info["root_height_min_m"] is not None:
            print(f"root height {info['root_height_min_m']:.3f} .. "
                  f"{info['root_height_max_m']:.3f} m")
    return 0


def _cmd_list(args: argparse.Namespace) -> int:
    names = bundled_recordings()
    if args.json:
        print(json.dumps(names))
    else:
        for name in names:
            print(f"bundled:{name}")
    return 0


def listen(source_url: str, skeleton: str, *, duration: float | None = None,
           frames: int | None = None, save_raw: str | None = None, fmt: str = "auto",
           avatar: str | int | None = None, on_event=None, on_progress=None, stop=None) -> dict:
    """Receives a stream until `duration` seconds, `frames` frames, end of input or `stop()`
    is true; returns the summary (counters, fps, latency, connection events, `avatars`).

    The frames of each avatar on the stream are counted apart (`avatars`: index, name,
    frames, dropped, restarts... of each). `avatar` (a name, or an index) keeps one: the
    summary's counters are its own. `frames` counts the frames of one avatar (the kept one,
    or the first to reach it). An `avatar` that never came while frames of others did raises
    `capture.avatars.AvatarNotSeenError`, naming those that came.
    """
    check_limits(duration, frames)
    from .avatars import avatar_selector
    from .bvh import read_bvh
    from .monitor import StreamMonitor
    from .rawcapture import RawCaptureWriter, skeleton_header_text
    from .sources import open_transport, Source
    from .stream_layout import StreamLayout

    selector = avatar_selector(avatar)
    header_path = resolve_path(skeleton)
    header = read_bvh(header_path, unit=None)
    layout = StreamLayout(header.skeleton)
    transport = open_transport(source_url)
    raw = None
    if save_raw is not None:
        raw = RawCaptureWriter(save_raw, source=source_url,
                               transport="datagram" if transport.datagram else "stream",
                               time_origin=time.time(),
                               skeleton_bvh=skeleton_header_text(
                                   header_path.read_text(errors="replace")))
    monitor = StreamMonitor(selector)
    start = time.monotonic()
    next_report = start + 1.0
    with Source(transport, layout, fmt=fmt, raw=raw, on_event=on_event) as source:
        while not source.exhausted:
            left = None if duration is None else duration - (time.monotonic() - start)
            if left is not None and left <= 0:
                break
            if stop is not None and stop():
                break
            got = source.read(0.2 if left is None else max(0.0, min(0.2, left)))
            if monitor.add_up_to(got, frames):
                break
            if on_progress is not None and time.monotonic() >= next_report:
                next_report += 1.0
                on_progress(monitor.summary(source.stats()))
        summary = monitor.summary(source.stats())
        summary["source"] = source.name
        summary["events"] = [message for _, message in source.events]
    if frames is not None and selector is None:  # (the decoder may have read further)
        summary["frames"] = sum(r["frames"] for r in summary["avatars"])
    if selector is not None and monitor.avatars and not monitor.count:
        raise selector.not_seen(monitor.avatars)
    return summary


def avatars_text(avatars: list[dict]) -> str:
    """`Avatar00 12, Avatar01 11 (not kept)`: the avatars of a summary for a status line."""
    return ", ".join(f"{a['name'] or '(no name)'} {a['frames']}"
                     + ("" if a.get("kept", True) else " (not kept)") for a in avatars)


def _cmd_listen(args: argparse.Namespace) -> int:
    stopping = {"flag": False}

    def on_sigint(signum, frame):
        stopping["flag"] = True

    previous = signal.signal(signal.SIGINT, on_sigint)

    def progress(s: dict) -> None:
        fps = f"{s['fps']:.1f}" if s["fps"] else "-"
        lat = f"{s['latency_ms']:.1f} ms" if s["latency_ms"] is not None else "-"
        who = f"  avatars {avatars_text(s['avatars'])}" if s.get("avatars") else ""
        print_status(f"frames {s['frames']}  fps {fps}  dropped {s['dropped']}  corrupt "
                     f"{s['corrupt']}  latency {lat}{who}")

    from .avatars import AvatarNotSeenError

    try:
        summary = listen(args.source, args.skeleton, duration=args.duration, frames=args.frames,
                         save_raw=args.save_raw, fmt=args.format, avatar=args.avatar,
                         on_event=print_event, on_progress=progress,
                         stop=lambda: stopping["flag"])
    except AvatarNotSeenError as exc:
        return avatar_not_seen(exc, args.json)
    finally:
        signal.signal(signal.SIGINT, previous)
    if args.json:
        # the monitor gives None for a figure it cannot compute; the guard keeps the output
        # valid JSON whatever a future field holds
        print(json.dumps(_json_safe(summary), indent=2, allow_nan=False))
    else:
        _print_listen_summary(summary)
    return _no_frame_status(summary)


def avatar_not_seen(exc, as_json: bool) -> int:
    """Reports a chosen avatar that never came (`capture.avatars.AvatarNotSeenError`): the
    error on stderr, with `--json` also `{"error", "exit_status", "avatars"}` on stdout;
    returns the exit status, 2."""
    import sys

    print(f"sitrelax: error: {exc}", file=sys.stderr)
    if as_json:
        print(json.dumps(_json_safe({"error": str(exc), "exit_status": 2,
                                     "avatars": exc.avatars}), allow_nan=False))
    return 2


def no_frame_reason(summary: dict) -> str:
    """Why a listen's or a recording's `summary` holds no frame: its last event, and how many
    candidate frames were rejected as corrupt, if any (bytes came, only none made a frame)."""
    why = summary["events"][-1] if summary.get("events") else "nothing arrived"
    rejected = summary.get("corrupt") or 0
    if rejected:
        why += (f"; {rejected} candidate frame{'s' if rejected != 1 else ''} rejected as "
                f"corrupt (cut short, followed by stray bytes, or holding NaN)")
    return why


def _no_frame_status(summary: dict) -> int:
    """0 once a frame came; else names why on stderr (`no_frame_reason`) and returns 2."""
    if summary["frames"]:
        return 0
    import sys

    print(f"sitrelax: error: no frame received from {summary['source']} "
          f"({no_frame_reason(summary)})", file=sys.stderr)
    return 2


def _print_listen_summary(summary: dict) -> None:
    fps = f"{summary['fps']:.1f}" if summary["fps"] else "-"
    lat = (f"{summary['latency_ms']:.2f} ms mean, {summary['latency_max_ms']:.2f} ms max"
           if summary["latency_ms"] is not None else "-")
    duration = (f"{summary['duration_s']:.2f} s" if summary["duration_s"] is not None
                else "n/a")
    print(f"source      {summary['source']}")
    print(f"frames      {summary['frames']} (indices {summary['first_index']} .. "
          f"{summary['last_index']})")
    print(f"fps         {fps} over {duration}")
    print(f"dropped     {summary['dropped']}   corrupt {summary['corrupt']}   resynced "
          f"{summary['resynced']}   reconnects {summary['reconnects']}")
    print(f"latency     {lat}")
    for a in summary.get("avatars", ()):
        print(f"avatar      {a['name'] or '(no name)'} (index {a['index']}): {a['frames']} "
              f"frames, dropped {a['dropped'] or 0}, restarts {a['restarts'] or 0}"
              + ("" if a["kept"] else " (not kept)"))


def _cmd_replay(args: argparse.Namespace) -> int:
    from .replay import Replay, open_sink

    path = resolve_path(args.file)
    if str(path).lower().endswith(".bvh"):
        replay = Replay.from_bvh(path, fmt=args.format, with_displacement=not args.no_displacement,
                                 with_reference=args.reference, avatar_name=args.avatar,
                                 start_index=args.start_index,
                                 restart_index=args.restart_index)
    else:
        replay = Replay.from_raw(path)
    sink = open_sink(tcp=args.tcp, udp=args.udp, serial_url=args.serial, on_event=print_event,
                     max_datagram=args.max_datagram)
    print_event(f"replaying {replay.description} to {sink.name} at {args.rate:g}x"
                + (", looping" if args.loop else ""))

    import threading

    stop = threading.Event()
    previous = signal.signal(signal.SIGINT, lambda signum, frame: stop.set())
    try:
        if args.wait_client and hasattr(sink, "wait_for_client"):
            print_event("waiting for a client")
            sink.wait_for_client(stop)
        stats = replay.run(sink, rate=args.rate, loop=args.loop, stop=stop,
                           max_frames=args.frames,
                           progress=lambda s: print_status(f"sent {s.frames_sent} frames in "
                                                           f"{s.elapsed_s:.1f} s"))
    finally:
        signal.signal(signal.SIGINT, previous)
        sink.close()
    result = {"frames_sent": stats.frames_sent, "bytes_sent": stats.bytes_sent,
              "loops": stats.loops, "elapsed_s": stats.elapsed_s, "target": sink.name}
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print_status(f"sent {stats.frames_sent} frames ({stats.bytes_sent} bytes) in "
                     f"{stats.elapsed_s:.2f} s to {sink.name}", final=True)
    return 0


def register(subparsers) -> dict:
    """Adds the `bvh` and `capture` command groups to the top-level parser; returns the groups'
    subparsers so packages above can add their own commands to them."""
    groups = {"capture": _register_capture(subparsers)}
    bvh = subparsers.add_parser("bvh", help="inspect BVH motion files")
    sub = bvh.add_subparsers(dest="bvh_command", required=True)
    info = sub.add_parser("info", help="summarise a BVH file")
    info.add_argument("file", help="a .bvh path or bundled:NAME (see `sitrelax bvh list`)")
    info.add_argument("--unit", default="auto",
                      help="length unit of the file: auto (from the skeleton profile), m, dm, cm, "
                           "mm, in, cmu, or metres per unit (default: auto)")
    info.add_argument("--json", action="store_true", help="machine-readable output")
    info.set_defaults(func=_cmd_info)
    lst = sub.add_parser("list", help="list the bundled recordings")
    lst.add_argument("--json", action="store_true", help="machine-readable output")
    lst.set_defaults(func=_cmd_list)
    return groups


def _register_capture(subparsers) -> None:
    from .constants import FORMATS

    cap = subparsers.add_parser("capture",
                                help="Perception Neuron streams: replay, listen and record")
    sub = cap.add_subparsers(dest="capture_command", required=True)

    rp = sub.add_parser("replay", help="play a BVH file or raw capture as Axis Neuron would")
    rp.add_argument("file", help="a .bvh file, bundled:NAME, or a raw capture")
    to = rp.add_mutually_exclusive_group(required=True)
    to.add_argument("--tcp", metavar="[HOST]:PORT",
                    help="serve TCP clients on this address (host defaults to 127.0.0.1)")
    to.add_argument("--udp", metavar="HOST:PORT", help="send datagrams to this address")
    to.add_argument("--serial", metavar="URL", help="write to a serial port or pyserial URL")
    rp.add_argument("--format", choices=FORMATS, default="binary",
                    help="binary (current header), binary-old or string (default: binary)")
    rp.add_argument("--rate", type=number(0), default=1.0,
                    help="speed relative to real time; 0 sends as fast as possible")
    rp.add_argument("--loop", action="store_true", help="start over at the end, forever")
    rp.add_argument("--no-displacement", action="store_true",
                    help="send rotations only (plus the hips position)")
    rp.add_argument("--reference", action="store_true", help="send the 6-float reference block")
    rp.add_argument("--avatar", default="Avatar00",
                    help="with a .bvh file: the avatar name the frames carry (default "
                         "Avatar00; a raw capture replays its avatars as received)")
    rp.add_argument("--start-index", type=number(0, 0xFFFFFFFF, whole=True), default=0,
                    help="first frame index, 0 to 4294967295 (the header's u32; it wraps "
                         "to 0 after that, as Axis's does)")
    rp.add_argument("--restart-index", action="store_true",
                    help="with --loop: start the frame index over on every pass")
    rp.add_argument("--max-datagram", type=number(1, whole=True), default=None, metavar="BYTES",
                    help="with --udp: split each frame into datagrams of at most BYTES")
    rp.add_argument("--wait-client", action="store_true",
                    help="with --tcp: start only once a client has connected")
    rp.add_argument("--frames", type=number(1, whole=True), default=None,
                    help="stop after N frames, at least 1")
    rp.add_argument("--json", action="store_true", help="machine-readable summary")
    rp.set_defaults(func=_cmd_replay)

    ls = sub.add_parser("listen", help="receive a stream and report rate, drops and latency")
    ls.add_argument("source", help="tcp://HOST:PORT, udp://[HOST]:PORT, serial://DEVICE?baudrate=N, "
                                   "a pyserial URL, or file:PATH (raw capture)")
    ls.add_argument("--skeleton", required=True,
                    help="the BVH header paired with the stream (path or bundled:NAME)")
    ls.add_argument("--duration", type=number(0, low_open=True), default=None,
                    help="stop after S seconds, > 0 (default: until Ctrl-C or the source ends)")
    ls.add_argument("--frames", type=number(1, whole=True), default=None,
                    help="stop after N frames of one avatar, at least 1")
    ls.add_argument("--format", choices=("auto", "binary", "string"), default="auto",
                    help="stream format (default: detected)")
    ls.add_argument("--save-raw", metavar="PATH", default=None,
                    help="also write the exact bytes received to a raw capture")
    ls.add_argument("--avatar", metavar="NAME_OR_INDEX", default=None,
                    help="count only this avatar's frames (its name, e.g. Avatar01, or its "
                         "index: digits are an index); every avatar on the stream is listed with its frame count "
                         "either way, and one that never comes is an error naming those that "
                         "did")
    ls.add_argument("--json", action="store_true", help="print one summary object")
    ls.set_defaults(func=_cmd_listen)
    return sub
