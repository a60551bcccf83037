"""Benchmark entries of the capture package, and the record every package uses to declare one.

Timing and reporting live in `solver.bench`; a package only says what to run and, where one
exists, what independent implementation to compare against.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable


@dataclass(frozen=True)
class BenchCase:
    """One benchmark: `run` is timed; `baseline`, when given, is timed in the same session.

    setup : called once before any timing; returns the argument passed to run and baseline.
    """

    name: str
    description: str
    setup: Callable[[], object]
    run: Callable[[object], object]
    baseline: Callable[[object], object] | None = None
    baseline_name: str | None = None
    repeats: int = 15
    baseline_repeats: int = 3
    per_second: int | None = None  # items handled per run, to report a throughput
    warmup: bool = True  # one untimed run first (off for entries that start fresh each run)
    # run and baseline return the seconds of the part they time themselves (the rest of what
    # they do, such as waiting for the work before to settle, is not timed)
    self_timed: bool = False


AXIS_RECORDING = "bundled:axis_neuron_standing_yxz.bvh"


def _read_setup() -> str:
    from .recordings import resolve_path  # `sitrelax` starts without it

    return str(resolve_path(AXIS_RECORDING))


def _read(path: str):
    from .bvh import read_bvh

    return read_bvh(path)


def _bvhio_read(path: str):
    import bvhio

    return bvhio.readAsHierarchy(path)


def _fk_setup():
    from .bvh import read_bvh

    return read_bvh(_read_setup())


def _fk(bvh):
    return bvh.fk()


STREAM_FRAMES = 20_000


def _decode_setup():
    """20,000 frames of the 59-bone, 354-float layout in one byte string, and the layout."""
    from .bvh import read_bvh
    from .neuron import encode_binary
    from .stream_layout import StreamLayout

    bvh = read_bvh(_read_setup())
    layout = StreamLayout(bvh.skeleton)
    payload = layout.to_payload(bvh.motion.channels, True, False)
    frames = [encode_binary(payload[k % len(payload)], frame_index=k)
              for k in range(STREAM_FRAMES)]
    return layout, frames


def _decode(arg):
    from .neuron import StreamDecoder

    layout, frames = arg
    decoder = StreamDecoder(counts=layout.counts())
    n = 0
    for blob in frames:  # one read per frame, as TCP delivers them
        n += len(decoder.feed(blob))
    n += len(decoder.flush())  # the last frame: nothing follows it to confirm it sooner
    assert n == STREAM_FRAMES, n
    return n


def _tcp_setup():
    from .bvh import read_bvh
    from .stream_layout import StreamLayout

    path = _read_setup()
    return path, StreamLayout(read_bvh(path).skeleton)


def _tcp(arg):
    """Replays the whole recording over loopback TCP as fast as possible and receives it."""
    from .replay import Replay, ReplayThread, TcpServerSink
    from .sources import open_source

    path, layout = arg
    replay = Replay.from_bvh(path)
    sink = TcpServerSink("127.0.0.1", 0)
    thread = ReplayThread(replay, sink, wait_for_client=True, rate=0).start()
    source = open_source(f"tcp://127.0.0.1:{sink.port}", layout)
    got = 0
    while got < len(replay):
        got += len(source.read(1.0))
    thread.stop()
    source.close()
    return got


def cases() -> list[BenchCase]:
    return [
        BenchCase(
            "bvh_read",
            "parse the 17 s, 59-joint Axis Neuron recording (2,156 frames x 180 channels)",
            _read_setup, _read, _bvhio_read, "bvhio.readAsHierarchy",
        ),
        BenchCase(
            "bvh_fk",
            "world positions and rotations of all 59 joints in all 2,156 frames",
            _fk_setup, _fk,
        ),
        BenchCase(
            "stream_decode",
            f"decode {STREAM_FRAMES:,} binary frames of 354 floats, one read each",
            _decode_setup, _decode, repeats=7, per_second=STREAM_FRAMES,
        ),
        BenchCase(
            "stream_tcp",
            "replay the 2,156-frame recording over loopback TCP unpaced and receive it",
            _tcp_setup, _tcp, repeats=5, per_second=2156,
        ),
    ]
