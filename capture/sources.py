"""Stream sources opened from a URL: TCP, UDP, serial lines (any pyserial URL) and raw captures.

    tcp://HOST:PORT                  connect to Axis as a client; reconnect with back-off
    udp://[HOST]:PORT                bind and receive datagrams (HOST defaults to 127.0.0.1;
                                     give 0.0.0.0 to receive from other machines)
    serial://DEVICE?baudrate=N       a serial device (serial:///dev/ttyUSB0, serial://COM3)
    socket://, rfc2217://, loop://   any other pyserial URL
    file:PATH                        a raw capture (see `capture.rawcapture`)

A `Source` decodes what its transport receives into `NeuronFrame`s stamped with the receive
time, counts dropped, corrupt and resynchronised frames, and reports connection events (a lost
peer, a reconnection and the gap it left) through `events` and an optional callback.
"""

from __future__ import annotations

import ipaddress
import logging
import select
import socket
import time
from pathlib import Path
from typing import Callable, Iterator
from urllib.parse import parse_qs, urlsplit

from .neuron import TOKEN, NeuronFrame, StreamDecoder
from .rawcapture import (CONNECTED, DATA, DISCONNECTED, RawCaptureWriter, check_raw_capture,
                         iter_raw_capture)
from .stream_layout import StreamLayout

log = logging.getLogger(__name__)

Record = tuple[int, float, bytes]  # kind, Unix receive time, bytes
_RECV_SIZE = 1 << 16
_RCVBUF = 4 << 20
_PYSERIAL_SCHEMES = ("socket", "rfc2217", "loop", "spy", "alt", "hwgrep", "cp2110")


class StreamSourceError(ValueError):
    """A source URL that cannot be opened as given."""


class UnknownProtocolError(StreamSourceError):
    """Bytes arrive, but no Perception Neuron frame is in them (another protocol on the port)."""


UNKNOWN_PROTOCOL_AFTER = 1.0  # seconds of bytes without a frame before they are named
# A byte stream quiet this long (s) has paused: a whole frame that ends where its bytes end is
# accepted without waiting for the next one. Judged from receive times alone, so that a raw
# capture of the stream (a journal) decodes to exactly the frames the live reader returned.
PAUSE_S = 0.1


def describe_bytes(data: bytes, first_read: int | None = None) -> str:
    """What the first bytes of a stream look like, for a message about an unknown protocol.

    data : the first bytes received; first_read : the size of the first read or datagram.
    """
    head = data[:16].hex(" ")
    for order in ("big", "little"):
        size = int.from_bytes(data[:4], order) if len(data) >= 4 else -1
        if 0 < size < 1 << 24:
            zlib = len(data) >= 6 and data[4] == 0x78 and data[5] in (0x01, 0x5E, 0x9C, 0xDA)
            if zlib or (first_read is not None and size in (first_read - 4, first_read)):
                return (f"they look like length-prefixed messages ({order}-endian u32 length "
                        f"{size}{', zlib-compressed' if zlib else ''}), as Axis Studio's "
                        f"advanced broadcast sends; set Axis to its BVH broadcast (binary or "
                        f"string) for this port (first bytes {head})")
    if data[:2] == TOKEN:
        return f"they start with the binary token but no frame fits (first bytes {head})"
    return f"first bytes {head}"


def is_loopback(host: str) -> bool:
    """Whether every address `host` names is a loopback one (127.0.0.0/8, ::1)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        pass
    try:
        infos = socket.getaddrinfo(host, None)
    except OSError:
        return False
    return bool(infos) and all(ipaddress.ip_address(i[4][0]).is_loopback for i in infos)


def parse_host_port(text: str, *, default_host: str = "127.0.0.1", what: str = "address"
                    ) -> tuple[str, int]:
    """`HOST:PORT` or `:PORT` -> (host, port); IPv6 hosts in brackets."""
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise StreamSourceError(f"Expected {what} as HOST:PORT or :PORT, got {text!r}")
    host = host.strip("[]") or default_host
    return host, int(port)


# -- transports ---------------------------------------------------------------------------------


class TcpTransport:
    """A TCP client that reconnects with exponential back-off when the peer goes away."""

    datagram = False
    exhausted = False

    def __init__(self, host: str, port: int, *, backoff: tuple[float, float] = (0.1, 2.0),
                 connect_timeout: float = 2.0):
        self.host, self.port = host, port
        self.backoff = backoff
        self.connect_timeout = connect_timeout
        self.sock: socket.socket | None = None
        self._delay = backoff[0]
        self._next_try = 0.0
        self.last_error: str | None = None

    @property
    def name(self) -> str:
        return f"tcp://{self.host}:{self.port}"

    def poll(self, timeout: float) -> list[Record]:
        if self.sock is None:
            wait = self._next_try - time.monotonic()
            if wait > 0:
                time.sleep(min(wait, timeout))
                return []
            try:
                sock = socket.create_connection((self.host, self.port),
                                                timeout=min(self.connect_timeout, max(timeout, 0.05)))
            except OSError as exc:
                self.last_error = f"cannot connect to {self.host}:{self.port} ({exc.strerror or exc})"
                self._next_try = time.monotonic() + self._delay
                retry = self._delay
                self._delay = min(self._delay * 2, self.backoff[1])
                return [(DISCONNECTED, time.time(), f"{self.last_error}; retrying in {retry:.1f} s"
                         .encode())]
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, _RCVBUF)
            sock.settimeout(None)
            self.sock = sock
            self._delay = self.backoff[0]
            return [(CONNECTED, time.time(), f"connected to {self.host}:{self.port}".encode())]
        ready, _, _ = select.select([self.sock], [], [], timeout)
        if not ready:
            return []
        try:
            data = self.sock.recv(_RECV_SIZE)
            reason = "the peer closed the connection"
        except OSError as exc:
            data = b""
            reason = f"connection lost ({exc.strerror or exc})"
        now = time.time()
        if data:
            return [(DATA, now, data)]
        self.sock.close()
        self.sock = None
        self._next_try = time.monotonic() + self._delay
        return [(DISCONNECTED, now, f"{reason}; reconnecting".encode())]

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None


class UdpTransport:
    """Binds a UDP port and receives datagrams (one frame each)."""

    datagram = True
    exhausted = False

    def __init__(self, host: str, port: int):
        self.sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET,
                                  socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, _RCVBUF)
        try:
            self.sock.bind((host, port))
        except OSError as exc:
            self.sock.close()
            raise StreamSourceError(f"Cannot bind UDP {host}:{port}: {exc.strerror or exc}") from None
        self.sock.setblocking(False)
        self.host, self.port = self.sock.getsockname()[:2]

    @property
    def name(self) -> str:
        return f"udp://{self.host}:{self.port}"

    def poll(self, timeout: float) -> list[Record]:
        ready, _, _ = select.select([self.sock], [], [], timeout)
        out: list[Record] = []
        if not ready:
            return out
        while True:
            try:
                data = self.sock.recv(_RECV_SIZE)
            except (BlockingIOError, InterruptedError):
                return out
            out.append((DATA, time.time(), data))

    def close(self) -> None:
        self.sock.close()


class SerialTransport:
    """Reads a byte stream from a pyserial port (a device, or a socket://, loop://... URL)."""

    datagram = False
    exhausted = False

    def __init__(self, port, name: str | None = None):
        self.port = port
        self._name = name or getattr(port, "name", None) or getattr(port, "port", "serial")

    @property
    def name(self) -> str:
        return str(self._name)

    def poll(self, timeout: float) -> list[Record]:
        import serial

        if self.exhausted:
            return []
        try:
            self.port.timeout = timeout
            data = self.port.read(max(1, self.port.in_waiting))
        except (serial.SerialException, OSError) as exc:
            # A bridge unplugged or its peer gone: the end of this source, as the end of a
            # file is, so the frames that came are kept (and a take recording is stored)
            # rather than thrown away with an error.
            self.exhausted = True
            return [(DISCONNECTED, time.time(),
                     f"the serial port {self.name} went away ({exc}); the source has "
                     f"ended".encode())]
        return [(DATA, time.time(), data)] if data else []

    def close(self) -> None:
        self.port.close()


class RawFileTransport:
    """Plays back the records of a raw capture as fast as they are asked for.

    The whole file is checked first (`check_raw_capture`): a damaged one raises
    `RawCaptureError` before any of its records is delivered.
    """

    def __init__(self, path: str | Path, batch: int = 256):
        self.path = Path(path)
        check_raw_capture(self.path)
        self.header, self._records = iter_raw_capture(self.path)
        self._iter = iter(self._records)
        self.datagram = self.header.get("transport", "stream") == "datagram"
        self.origin = float(self.header.get("time_origin", 0.0))
        self.batch = batch
        self.exhausted = False

    @property
    def name(self) -> str:
        return f"file:{self.path}"

    @property
    def truncated(self) -> bool:
        return self._records.truncated

    def poll(self, timeout: float) -> list[Record]:
        out: list[Record] = []
        for rec in self._iter:
            out.append((rec.kind, self.origin + rec.t, rec.data))
            if len(out) >= self.batch:
                return out
        self.exhausted = True
        return out

    def close(self) -> None:
        self._records.close()
        self._iter = iter(())
        self.exhausted = True


# -- the source -------------------------------------------------------------------------------


class Source:
    """Decoded frames from a transport, with counters and connection events.

    layout : the paired skeleton's `StreamLayout`; frames that do not fit it are rejected, and
        a stream none of whose frames fits raises `LayoutMismatchError`.
    raw : optional `RawCaptureWriter` receiving every record exactly as received.
    on_event : optional callback taking a one-line message (connections, gaps).
    """

    def __init__(self, transport, layout: StreamLayout | None = None, *, fmt: str = "auto",
                 raw: RawCaptureWriter | None = None,
                 on_event: Callable[[str], None] | None = None):
        self.transport = transport
        self.layout = layout
        self.decoder = StreamDecoder(counts=layout.counts() if layout else None,
                                     datagram=transport.datagram, fmt=fmt)
        self.raw = raw
        self.on_event = on_event
        self.events: list[tuple[float, str]] = []
        self.connects = 0
        self.disconnects = 0
        self._down_since: float | None = None
        self._resume_pending = False
        self._index_before_gap: int | None = None
        self._flushed = False
        self.closed = False
        self._first_data: bytes | None = None
        self._first_data_t = self._last_data_t = 0.0
        self._first_datagram_size = 0
        self._data_bytes = 0
        self._last_fed_t: float | None = None

    @property
    def name(self) -> str:
        return self.transport.name

    @property
    def exhausted(self) -> bool:
        return self.transport.exhausted and self._flushed

    @property
    def reconnects(self) -> int:
        return max(0, self.connects - 1)

    def _event(self, t: float, message: str) -> None:
        self.events.append((t, message))
        log.info("%s: %s", self.name, message)
        if self.on_event is not None:
            self.on_event(message)

    def read(self, timeout: float = 0.5) -> list[NeuronFrame]:
        """Frames received within about `timeout` seconds (possibly none)."""
        if self.closed:
            return []
        frames: list[NeuronFrame] = []
        records = self.transport.poll(timeout)
        if not records and self._paused_before(time.time()):
            frames.extend(self.decoder.settle())  # a pause confirms a frame ending there
        for kind, t, data in records:
            if self.raw is not None:
                self.raw.write(kind, t, data)
            if kind == DATA:
                if self.raw is not None:  # (the time as the raw capture gives it back)
                    origin = self.raw.time_origin
                    t_fed = origin + (t - origin)
                else:
                    t_fed = t
                if self._paused_before(t_fed):  # (the same pause, seen again from a journal)
                    frames.extend(self.decoder.settle())
                self._last_fed_t = t_fed
                self._note_data(t, data)
                frames.extend(self.decoder.feed(data, t))
            elif kind == DISCONNECTED:
                frames.extend(self.decoder.flush(t))
                if self._down_since is None:
                    self._down_since = t
                    self.disconnects += 1 if self.connects else 0
                    self._index_before_gap = self.decoder.stats.last_index
                    self._event(t, data.decode("utf-8", "replace") or "disconnected")
                elif not self.connects:
                    self._event(t, data.decode("utf-8", "replace"))
            elif kind == CONNECTED:
                self.connects += 1
                if self.connects > 1 and self._down_since is not None:
                    self._event(t, f"reconnected after {t - self._down_since:.2f} s")
                    self._resume_pending = True
                else:
                    self._event(t, data.decode("utf-8", "replace") or "connected")
                self._down_since = None
        if self.transport.exhausted and not self._flushed:
            frames.extend(self.decoder.flush())
            self._flushed = True
            if getattr(self.transport, "truncated", False):  # (a raw capture cut short)
                self._event(time.time(), f"{self.name}: the last record is cut short (the "
                                         "capture was interrupted); it is ignored")
        if frames and self._resume_pending:
            self._report_resume(frames[0])
        dec = self.decoder
        if self.layout is not None and dec.mismatch and dec.stats.frames == 0 and (
                dec.stats.corrupt >= 3 or self.transport.exhausted):
            raise self.layout.mismatch(*dec.mismatch)
        if dec.stats.frames == 0 and self._data_span() >= UNKNOWN_PROTOCOL_AFTER:
            raise UnknownProtocolError(
                f"Expected a Perception Neuron BVH broadcast from {self.name}, got "
                f"{self._data_bytes} bytes in {self._data_span():.1f} s without a frame in "
                f"them: {describe_bytes(self._first_data, self._first_datagram_size)}")
        return frames

    def _paused_before(self, t: float) -> bool:
        """Whether the stream was quiet for `PAUSE_S` before time `t` (Unix s)."""
        return self._last_fed_t is not None and t - self._last_fed_t >= PAUSE_S

    def _note_data(self, t: float, data: bytes) -> None:
        if self._first_data is None:
            self._first_data, self._first_data_t = bytes(data[:64]), t
            self._first_datagram_size = len(data)
        self._last_data_t = t
        self._data_bytes += len(data)

    def _data_span(self) -> float:
        """Seconds between the first and the latest bytes received (0 before any)."""
        if self._first_data is None:
            return 0.0
        return self._last_data_t - self._first_data_t

    def _report_resume(self, frame: NeuronFrame) -> None:
        self._resume_pending = False
        before, after = self._index_before_gap, frame.frame_index
        if before is None or after is None:
            self._event(frame.received_at or time.time(), "frames flow again")
            return
        step = (after - before) & 0xFFFFFFFF
        if step > 0x7FFFFFFF or step == 0:
            self._event(frame.received_at or time.time(),
                        f"frames flow again; the sender restarted at index {after}")
        else:
            self._event(frame.received_at or time.time(),
                        f"frames flow again at index {after}: {step - 1} frames missed "
                        f"after index {before}")

    def channels(self, frame: NeuronFrame):
        """The frame's values as the paired header's channels (C,) float64."""
        if self.layout is None:
            raise StreamSourceError("A skeleton header is needed to map frames to channels")
        return self.layout.to_channels(frame.values, frame.with_displacement,
                                       frame.with_reference)

    def stats(self) -> dict:
        """Counters so far: frames, dropped, corrupt, resynced, ..., reconnects, and
        `avatars`: each avatar's counters (`DecoderStats.avatar_dicts`)."""
        out = self.decoder.stats.as_dict()
        out.update(reconnects=self.reconnects, disconnects=self.disconnects,
                   avatars=self.decoder.stats.avatar_dicts())
        return out

    def __iter__(self) -> Iterator[NeuronFrame]:
        while not self.closed and not self.exhausted:
            yield from self.read()

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self.transport.close()
            if self.raw is not None:
                self.raw.close()

    def __enter__(self) -> "Source":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_transport(url: str, **kw):
    """A transport for a source URL (see the module docstring)."""
    if url.startswith("file:"):
        path = url[len("file:"):]
        if path.startswith("//"):
            path = path[2:]
        return RawFileTransport(path)
    parts = urlsplit(url)
    scheme = parts.scheme.lower()
    if scheme == "tcp":
        host, port = parse_host_port(parts.netloc, what="tcp://HOST:PORT")
        return TcpTransport(host, port, **kw)
    if scheme == "udp":
        host, port = parse_host_port(parts.netloc, what="udp://[HOST]:PORT")
        return UdpTransport(host, port)
    if scheme == "serial" or scheme in _PYSERIAL_SCHEMES:
        import serial

        try:
            if scheme == "serial":
                device = parts.netloc + parts.path
                query = {k: v[-1] for k, v in parse_qs(parts.query).items()}
                baud = int(query.pop("baudrate", 115200))
                if query:
                    raise StreamSourceError(f"Unknown serial options {sorted(query)} in {url!r}")
                port = serial.serial_for_url(device, baudrate=baud, timeout=0.1)
            else:
                port = serial.serial_for_url(url, timeout=0.1)
        except (serial.SerialException, ValueError) as exc:
            if isinstance(exc, StreamSourceError):
                raise
            raise StreamSourceError(f"Cannot open serial source {url!r}: {exc}") from None
        return SerialTransport(port, url)
    raise StreamSourceError(
        "Expected a source URL tcp://HOST:PORT, udp://[HOST]:PORT, serial://DEVICE?baudrate=N, "
        f"a pyserial URL (socket://, rfc2217://, loop://) or file:PATH, got {url!r}"
    )


def open_source(url: str, layout: StreamLayout | None = None, **kw) -> Source:
    """Opens a source URL; keyword arguments go to `Source` (fmt, raw, on_event)."""
    return Source(open_transport(url), layout, **kw)
