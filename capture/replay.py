"""A replay server that plays a BVH file or a raw capture as Axis Neuron would broadcast it.

Over TCP it is the server (Axis's role): clients connect, and every frame goes to every connected
client. Over UDP it sends one datagram per frame to a host and port. Over a serial line (any
pyserial URL) it writes the byte stream. Frames are paced at real time times `rate` (a rate of 0
sends as fast as possible) and may loop forever with a frame index that keeps counting.

A raw capture replays byte for byte, with its recorded timing, and a recorded disconnect drops
the TCP clients (they reconnect as they would to Axis).
"""

from __future__ import annotations

import errno
import select
import socket
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from .bvh import read_bvh
from .cli_output import check_limits
from .neuron import FORMATS, encode_frame
from .rawcapture import DATA, DISCONNECTED, read_raw_capture
from .sources import StreamSourceError, is_loopback, parse_host_port
from .stream_layout import StreamLayout


class ReplayError(ValueError):
    """A replay that cannot start as asked (bad file, port in use, bad options)."""


# -- sinks ------------------------------------------------------------------------------------


class TcpServerSink:
    """Listens on HOST:PORT and sends every frame to every connected client."""

    datagram = False

    def __init__(self, host: str, port: int, on_event: Callable[[str], None] | None = None,
                 send_timeout: float = 2.0):
        self.on_event = on_event
        self.send_timeout = send_timeout
        try:
            self.server = socket.create_server((host, port), reuse_port=False)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise ReplayError(f"TCP port {port} on {host} is in use") from None
            raise ReplayError(f"Cannot listen on {host}:{port}: {exc.strerror or exc}") from None
        self.server.setblocking(False)
        self.clients: list[socket.socket] = []
        self.host, self.port = self.server.getsockname()[:2]
        if not is_loopback(self.host):
            self._say(f"warning: serving {self.name} to other machines too (the stream has no "
                      f"authentication); give no host, or 127.0.0.1, to keep it on this one")

    @property
    def name(self) -> str:
        return f"tcp://{self.host}:{self.port}"

    def _say(self, message: str) -> None:
        if self.on_event is not None:
            self.on_event(message)

    def _accept(self) -> None:
        while True:
            try:
                conn, addr = self.server.accept()
            except (BlockingIOError, InterruptedError):
                return
            conn.setblocking(True)
            conn.settimeout(self.send_timeout)
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.clients.append(conn)
            self._say(f"client {addr[0]}:{addr[1]} connected ({len(self.clients)} connected)")

    def wait(self, seconds: float) -> None:
        """Sleeps up to `seconds`, accepting clients meanwhile."""
        ready, _, _ = select.select([self.server], [], [], max(0.0, seconds))
        if ready:
            self._accept()

    def wait_for_client(self, stop: threading.Event, timeout: float | None = None) -> bool:
        end = None if timeout is None else time.monotonic() + timeout
        while not self.clients and not stop.is_set():
            if end is not None and time.monotonic() > end:
                return False
            self.wait(0.05)
        return bool(self.clients)

    def send(self, data: bytes) -> None:
        self._accept()
        for conn in list(self.clients):
            try:
                conn.sendall(data)
            except OSError as exc:
                self.clients.remove(conn)
                conn.close()
                self._say(f"client dropped ({exc.strerror or exc}); {len(self.clients)} connected")

    def disconnect_all(self) -> None:
        for conn in self.clients:
            conn.close()
        if self.clients:
            self._say(f"disconnected {len(self.clients)} client(s)")
        self.clients = []

    def close(self) -> None:
        self.disconnect_all()
        self.server.close()


class UdpSink:
    """Sends each frame as one datagram to HOST:PORT, or, given `max_datagram`, as datagrams
    of at most that many bytes (as Axis splits a frame larger than the path allows: 1024 +
    the rest on macOS, 1480 + the rest on Windows)."""

    datagram = True

    def __init__(self, host: str, port: int, max_datagram: int | None = None):
        if max_datagram is not None and max_datagram < 1:
            raise ReplayError(f"Expected a datagram size >= 1, got {max_datagram}")
        self.max_datagram = max_datagram
        self.addr = (host, port)
        self.sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET,
                                  socket.SOCK_DGRAM)

    @property
    def name(self) -> str:
        return f"udp://{self.addr[0]}:{self.addr[1]}"

    def wait(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)

    def send(self, data: bytes) -> None:
        size = self.max_datagram or len(data) or 1
        for k in range(0, max(len(data), 1), size):
            self.sock.sendto(data[k:k + size], self.addr)

    def disconnect_all(self) -> None:
        pass

    def close(self) -> None:
        self.sock.close()


class WriterSink:
    """Writes the byte stream to anything with `write(bytes)`: a pyserial port, a file."""

    datagram = False

    def __init__(self, writer, name: str = "serial", close: bool = True):
        self.writer = writer
        self._name = name
        self._close = close

    @property
    def name(self) -> str:
        return self._name

    def wait(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)

    def send(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            n = self.writer.write(view)
            view = view[n if n is not None else len(view):]
        flush = getattr(self.writer, "flush", None)
        if flush is not None:
            flush()

    def disconnect_all(self) -> None:
        pass

    def close(self) -> None:
        if self._close:
            self.writer.close()


def open_sink(*, tcp: str | None = None, udp: str | None = None, serial_url: str | None = None,
              on_event: Callable[[str], None] | None = None, max_datagram: int | None = None):
    """The sink for exactly one of `tcp` ([HOST]:PORT to listen on; HOST defaults to
    127.0.0.1), `udp` (HOST:PORT to send to, frames split into datagrams of at most
    `max_datagram` bytes if given) or `serial_url` (any pyserial URL)."""
    given = [x for x in (tcp, udp, serial_url) if x is not None]
    if len(given) != 1:
        raise ReplayError("Expected exactly one of --tcp, --udp or --serial")
    try:
        if tcp is not None:
            return TcpServerSink(*parse_host_port(tcp, what="--tcp [HOST]:PORT"),
                                 on_event=on_event)
        if udp is not None:
            return UdpSink(*parse_host_port(udp, what="--udp HOST:PORT"),
                           max_datagram=max_datagram)
    except StreamSourceError as exc:
        raise ReplayError(str(exc)) from None
    import serial

    try:
        port = serial.serial_for_url(serial_url, timeout=1, write_timeout=5)
    except (serial.SerialException, ValueError) as exc:
        raise ReplayError(f"Cannot open serial port {serial_url!r}: {exc}") from None
    return WriterSink(port, serial_url)


# -- programmes -------------------------------------------------------------------------------


@dataclass
class ReplayStats:
    frames_sent: int = 0
    bytes_sent: int = 0
    loops: int = 0
    elapsed_s: float = 0.0


class Replay:
    """A replay programme: what to send and when.

    Made by `Replay.from_bvh` (frames encoded as they are sent, frame indices counting on
    across loops) or `Replay.from_raw` (recorded bytes and timing, unchanged).
    """

    def __init__(self, times: np.ndarray, make: Callable[[int, int], tuple[int, bytes]],
                 duration: float, description: str):
        self.times = np.asarray(times, dtype=np.float64)
        self._make = make
        self.duration = duration
        self.description = description

    def __len__(self) -> int:
        return len(self.times)

    def item(self, k: int, loop: int = 0) -> tuple[int, bytes]:
        """The k-th record of the programme (its kind and bytes) on pass `loop`."""
        return self._make(k, loop)

    @classmethod
    def from_bvh(cls, path: str | Path, *, fmt: str = "binary", with_displacement: bool = True,
                 with_reference: bool = False, avatar_name: str = "Avatar00",
                 avatar_index: int = 0, start_index: int = 0,
                 restart_index: bool = False) -> "Replay":
        """Frames of a BVH file; looping, the index counts on, or with `restart_index` starts
        over at `start_index` on every pass (as an emulator looping its file does)."""
        if fmt not in FORMATS:
            raise ReplayError(f"Expected a format from {FORMATS}, got {fmt!r}")
        if not (isinstance(start_index, (int, np.integer)) and 0 <= start_index <= 0xFFFFFFFF):
            raise ReplayError(f"Expected a start index from 0 to 4294967295 (the header's u32), "
                              f"got {start_index!r}")
        bvh = read_bvh(path, unit=None)
        layout = StreamLayout(bvh.skeleton)
        payload = layout.to_payload(bvh.motion.channels, with_displacement, with_reference)
        n = len(payload)
        if n == 0:
            raise ReplayError(f"{path}: expected motion to replay, got no frames")
        options = dict(avatar_name=avatar_name, avatar_index=avatar_index,
                       with_displacement=with_displacement, with_reference=with_reference)

        def make(k: int, loop: int) -> tuple[int, bytes]:
            index = start_index + (0 if restart_index else loop * n) + k
            return DATA, encode_frame(payload[k], fmt, frame_index=index, **options)

        dt = bvh.motion.frame_time
        return cls(np.arange(n) * dt, make, n * dt,
                   f"{Path(path).name}: {n} frames at {1 / dt:.0f} fps, {fmt}")

    @classmethod
    def from_raw(cls, path: str | Path) -> "Replay":
        """A raw capture's data and disconnect records at their recorded times (the reader
        refuses a capture whose times are not finite or implausible, before anything is
        sent); a record stamped before the one ahead of it (a clock set back) goes at once."""
        cap = read_raw_capture(path)
        records = [r for r in cap.records if r.kind in (DATA, DISCONNECTED)]
        if not records:
            raise ReplayError(f"{path}: expected recorded data to replay, got none")
        t0 = records[0].t
        times = np.array([r.t - t0 for r in records])
        span = float(times.max())
        step = max(0.0, float(np.median(np.diff(times)))) if len(times) > 1 else 0.0

        def make(k: int, loop: int) -> tuple[int, bytes]:
            return records[k].kind, records[k].data

        cut = " (its last record, cut short, is left out)" if cap.truncated else ""
        return cls(times, make, span + step,
                   f"{Path(path).name}: {len(records)} records over {span:.2f} s{cut}")

    @classmethod
    def from_file(cls, path: str | Path, **kw) -> "Replay":
        """A BVH file (`.bvh`) or a raw capture (anything else)."""
        if str(path).lower().endswith(".bvh"):
            return cls.from_bvh(path, **kw)
        return cls.from_raw(path)

    def run(self, sink, *, rate: float = 1.0, loop: bool = False,
            stop: threading.Event | None = None, max_frames: int | None = None,
            progress: Callable[[ReplayStats], None] | None = None,
            progress_every: float = 1.0) -> ReplayStats:
        """Sends the programme through `sink` until it ends, `stop` is set or `max_frames`."""
        if rate < 0 or not np.isfinite(rate):
            raise ReplayError(f"Expected a rate >= 0 (0: as fast as possible), got {rate}")
        check_limits(None, max_frames, ReplayError)
        stop = stop or threading.Event()
        stats = ReplayStats()
        start = time.monotonic()
        next_report = start + progress_every
        loop_no = 0
        while not stop.is_set():
            base = loop_no * self.duration
            for k in range(len(self.times)):
                if rate > 0:
                    target = start + (base + self.times[k]) / rate
                    while True:
                        now = time.monotonic()
                        if now >= target or stop.is_set():
                            break
                        sink.wait(min(target - now, 0.1))
                if stop.is_set():
                    break
                kind, data = self._make(k, loop_no)
                if kind == DATA:
                    sink.send(data)
                    stats.frames_sent += 1
                    stats.bytes_sent += len(data)
                elif kind == DISCONNECTED:
                    sink.disconnect_all()
                if progress is not None and time.monotonic() >= next_report:
                    stats.elapsed_s = time.monotonic() - start
                    progress(stats)
                    next_report += progress_every
                if max_frames is not None and stats.frames_sent >= max_frames:
                    stop.set()
            else:
                stats.loops += 1
                loop_no += 1
                if loop:
                    continue
            break
        stats.elapsed_s = time.monotonic() - start
        return stats


class ReplayThread:
    """Runs a replay in a background thread (tests, demos): start, then stop or join."""

    def __init__(self, replay: Replay, sink, *, wait_for_client: bool = False, **run_kw):
        self.replay = replay
        self.sink = sink
        self.stop_event = threading.Event()
        self.stats: ReplayStats | None = None
        self.error: BaseException | None = None
        self._wait = wait_for_client
        self._kw = run_kw
        self._thread = threading.Thread(target=self._main, daemon=True)

    def _main(self) -> None:
        try:
            if self._wait and isinstance(self.sink, TcpServerSink):
                if not self.sink.wait_for_client(self.stop_event):
                    return
            self.stats = self.replay.run(self.sink, stop=self.stop_event, **self._kw)
        except BaseException as exc:  # reported to the owner through `error`
            self.error = exc

    def start(self) -> "ReplayThread":
        self._thread.start()
        return self

    def join(self, timeout: float | None = None) -> None:
        self._thread.join(timeout)

    def stop(self, close: bool = True) -> None:
        self.stop_event.set()
        self._thread.join(5)
        if close:
            self.sink.close()

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()
