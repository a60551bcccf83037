"""What both servers share: which addresses count as loopback, which Host and Origin names
they answer (DNS rebinding and cross-site pages are refused), a request size limit, and the
timeouts that keep idle connections from holding the server."""

from __future__ import annotations

import asyncio
import json
import re

from capture.sources import is_loopback

from .loopback import LOOPBACK, LOOPBACK_NAMES  # noqa: F401 (studio.net.LOOPBACK, as before)

HEAD_TIMEOUT = 10.0  # seconds a client has to send a request head
BODY_TIMEOUT = 30.0  # seconds a request body may pause between chunks
DECLARED_PAUSE = 1.0  # seconds a body refused on its declared size is still drained when paused
DRAIN_FACTOR, DRAIN_MAX = 4, 64 * 1024 * 1024  # bytes of a refused body still read and dropped


def exposure_warning(host: str, what: str) -> str | None:
    """The warning to show when a server is asked to listen beyond this machine."""
    if is_loopback(host):
        return None
    return (f"warning: the {what} listens on {host}, reachable from other machines; it has no "
            "authentication, and anyone who reaches it can run fits and read the pose library")


def allowed_names(host: str, extra=()) -> frozenset[str]:
    """The Host/Origin names a server answers: the loopback names, the address it listens on
    (unless a wildcard) and `extra` (lower case, no port)."""
    names = set(LOOPBACK_NAMES) | {n.strip().lower().strip("[]") for n in extra if n.strip()}
    if host not in ("0.0.0.0", "::", ""):
        names.add(host.lower().strip("[]"))
    return frozenset(names)


# a Host header exactly (RFC 9110: a name or an IPv4 address, or an IPv6 one in brackets, with
# an optional port) or an Origin (RFC 6454: scheme://host[:port]): no user part, path, query
# or anything else, which a lenient URL parser would read past to a name of ours
_HOST = r"(?:\[(?P<v6>[0-9A-Fa-f:.]+)\]|(?P<name>[A-Za-z0-9](?:[A-Za-z0-9.-]*[A-Za-z0-9])?))" \
        r"(?::[0-9]{1,5})?"
_HOST_HEADER = re.compile(_HOST)
_ORIGIN = re.compile(r"[A-Za-z][A-Za-z0-9+.-]*://" + _HOST)


def host_name(value: str) -> str | None:
    """The name part of a Host header (`name`, `name:port`, `[v6]:port`) or of an Origin
    (`scheme://name:port`), lower case; None when the value is not exactly one of these."""
    value = value.strip()
    match = (_ORIGIN if "://" in value else _HOST_HEADER).fullmatch(value)
    if match is None:
        return None
    return (match.group("v6") or match.group("name")).lower()


def foreign(headers: dict, names: frozenset[str]) -> str | None:
    """Why a request is refused for its Host or Origin header (None when both are ours; a
    request without Origin is not a browser's cross-site one and passes)."""
    host = headers.get("host")
    if host is None or host_name(host) not in names:
        return f"Host {(host or '')[:100]!r} is not one this server answers (see --allow-host)"
    origin = headers.get("origin")
    if origin is not None and host_name(origin) not in names:
        return f"Origin {origin[:100]!r} is not one this server answers (see --allow-host)"
    return None


class HostCheck:
    """ASGI middleware: 403 for a request whose Host or Origin names another site."""

    def __init__(self, app, names: frozenset[str]):
        self.app, self.names = app, names

    async def __call__(self, scope, receive, send):
        if scope["type"] in ("http", "websocket"):
            headers = {k.decode("latin-1").lower(): v.decode("latin-1")
                       for k, v in scope.get("headers") or ()}
            problem = foreign(headers, self.names)
            if problem:
                return await _reply(send, 403, problem)
        return await self.app(scope, receive, send)


NOT_HTTP = ("Not a valid HTTP/1.1 request: a malformed request line or header, a "
            "Content-Length that is not a whole number, a Host or Content-Length given twice, "
            "or a malformed chunk of the body")


def head_timeout_protocol(head_timeout: float = HEAD_TIMEOUT):
    """uvicorn's h11 protocol with a deadline for each request head: a connection that has not
    sent a whole head `head_timeout` seconds after connecting (or after its last answer) is
    closed, so idle connections cannot use up the server. Bytes that are no HTTP request get
    400 with a JSON body, as every other answer (uvicorn's own is plain text)."""
    import h11
    from uvicorn.protocols.http.h11_impl import H11Protocol

    class HeadTimeoutProtocol(H11Protocol):
        def send_400_response(self, msg: str) -> None:
            body = json.dumps({"detail": NOT_HTTP}).encode()
            head = h11.Response(status_code=400, reason=b"Bad Request",
                                headers=[(b"content-type", b"application/json"),
                                         (b"content-length", str(len(body)).encode()),
                                         (b"connection", b"close")])
            for event in (head, h11.Data(data=body), h11.EndOfMessage()):
                self.transport.write(self.conn.send(event))
            self.transport.close()

        def connection_made(self, transport) -> None:
            super().connection_made(transport)
            self._arm_head_timer()

        def on_response_complete(self) -> None:
            super().on_response_complete()
            self._arm_head_timer()

        def _arm_head_timer(self) -> None:
            self.loop.call_later(head_timeout, self._head_overdue, self.scope)

        def _head_overdue(self, scope) -> None:
            idle = self.cycle is None or self.cycle.response_complete
            if self.scope is scope and idle and not self.transport.is_closing():
                self.transport.close()

    return HeadTimeoutProtocol


class BodyLimit:
    """ASGI middleware: a request whose body is larger than `limit` bytes gets 413 (checked on
    Content-Length when given, and on the bytes as they arrive); a body that pauses over
    `timeout` seconds gets 408. Once the body is whole, the app's further `receive()` (a wait
    for the client to go away while its answer is computed) is the server's own, unbounded."""

    def __init__(self, app, limit: int, timeout: float = BODY_TIMEOUT):
        self.app = app
        self.limit = int(limit)
        self.timeout = float(timeout)

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        declared = dict(scope.get("headers") or ()).get(b"content-length")
        if declared is not None:
            try:
                size = int(declared)
            except ValueError:
                return await _reply(send, 400, "Content-Length is not a number")
            if size > self.limit:  # (a client that stops sending is answered within a second)
                await self._drain(receive, 0, pause=min(self.timeout, DECLARED_PAUSE))
                return await _reply(send, 413, self._message(size))
        seen = 0
        refused = False
        started = False
        whole = False  # the body has all come

        async def limited_receive():
            # past the limit: answer 413 here and tell the app the client has gone
            nonlocal seen, refused, whole
            if refused:
                return {"type": "http.disconnect"}
            if whole:  # (no body pause to time: the next message is the client leaving)
                return await receive()
            try:
                message = await asyncio.wait_for(receive(), self.timeout)
            except asyncio.TimeoutError:
                refused = True
                if not started:
                    await _reply(send, 408, f"Request body paused over {self.timeout:g} s")
                return {"type": "http.disconnect"}
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > self.limit:
                    refused = True
                    if not started:
                        if message.get("more_body", False):
                            await self._drain(receive, seen)
                        await _reply(send, 413, self._message(seen))
                    return {"type": "http.disconnect"}
                whole = not message.get("more_body", False)
            return message

        async def guarded_send(message):
            nonlocal started
            if refused:
                return  # the 413 went out already
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        await self.app(scope, limited_receive, guarded_send)

    async def _drain(self, receive, seen: int, pause: float | None = None) -> None:
        """Reads and drops the rest of a refused body, up to DRAIN_FACTOR times the limit:
        closing on unread bytes resets the connection, and the client may never see the 413.
        A body larger still is cut off, and one that pauses over `pause` seconds (default the
        body timeout) is no longer waited for."""
        cap = min(DRAIN_FACTOR * self.limit, DRAIN_MAX)
        while seen <= cap:
            try:
                message = await asyncio.wait_for(receive(), pause or self.timeout)
            except asyncio.TimeoutError:
                return
            if message["type"] != "http.request":
                return
            seen += len(message.get("body", b""))
            if not message.get("more_body", False):
                return

    def _message(self, size: int) -> str:
        return (f"Request body of {size} bytes is larger than this server's limit of "
                f"{self.limit} bytes")


async def _reply(send, status: int, detail: str) -> None:
    body = json.dumps({"detail": detail}).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"),
                            (b"content-length", str(len(body)).encode()),
                            (b"connection", b"close")]})
    await send({"type": "http.response.body", "body": body})


class Front:
    """The studio's public socket in front of viser's server (which answers only GET and its
    websocket): a request without a body passes through byte for byte (the page, then the
    websocket), one with a body over `limit` bytes gets 413, any other with a body 405, a
    request head over 64 KiB 431, and one whose Host or Origin is not in `names` 403 (its
    Origin is removed before viser's server, which takes no other); a head not sent within
    `head_timeout` seconds closes the connection. The first request of a connection is the one
    looked at: later requests on a kept-alive connection reach viser, which closes on anything
    but GET. Runs its own event loop in a thread; `port` is the one bound."""

    HEAD_LIMIT = 64 * 1024

    def __init__(self, host: str, port: int, backend_port: int, limit: int,
                 names: frozenset[str] | None = None, head_timeout: float = HEAD_TIMEOUT):
        import threading

        self.backend_port, self.limit = backend_port, int(limit)
        self.names = names if names is not None else allowed_names(host)
        self.head_timeout = float(head_timeout)
        self.loop = asyncio.new_event_loop()
        started = threading.Event()
        failure: list[BaseException] = []

        async def start():
            try:
                self.server = await asyncio.start_server(self._serve, host, port,
                                                         limit=self.HEAD_LIMIT)
                self.port = self.server.sockets[0].getsockname()[1]
            except BaseException as exc:  # reported to the caller below
                failure.append(exc)
            started.set()

        def run():
            asyncio.set_event_loop(self.loop)
            self.loop.create_task(start())
            self.loop.run_forever()

        self.thread = threading.Thread(target=run, name="sitrelax-studio-front", daemon=True)
        self.thread.start()
        started.wait(30)
        if failure:
            self.stop()
            raise failure[0]

    async def _serve(self, reader, writer) -> None:
        try:
            head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), self.head_timeout)
        except asyncio.LimitOverrunError:
            return await self._answer(writer, 431, "Request head larger than 64 KiB")
        except (asyncio.IncompleteReadError, asyncio.TimeoutError, ConnectionError):
            writer.close()
            return
        lines = head.decode("latin-1").split("\r\n")
        method = lines[0].split(" ", 1)[0]
        headers = {}
        for line in lines[1:]:
            name, _, value = line.partition(":")
            headers[name.strip().lower()] = value.strip()
        problem = foreign(headers, self.names)
        if problem:
            return await self._answer(writer, 403, problem)
        # checked here; viser's server takes only requests without an Origin (a foreign page
        # that finds its port directly is refused there)
        head = "\r\n".join(line for line in lines
                            if not line.lower().startswith("origin:")).encode("latin-1")
        try:
            length = int(headers.get("content-length", "0") or 0)
        except ValueError:
            return await self._answer(writer, 400, "Content-Length is not a number")
        chunked = "chunked" in headers.get("transfer-encoding", "").lower()
        if length > self.limit:
            await self._drain(reader, length)
            return await self._answer(writer, 413, f"Request body of {length} bytes is larger "
                                                   f"than this server's limit of {self.limit} "
                                                   "bytes")
        if method != "GET" or length or chunked:
            await self._drain(reader, length)
            return await self._answer(writer, 405, "The studio takes GET requests and its "
                                                   "websocket only", allow=True)
        try:
            up_reader, up_writer = await asyncio.open_connection("127.0.0.1", self.backend_port)
        except OSError:
            return await self._answer(writer, 503, "The studio is not running")
        up_writer.write(head)
        await asyncio.gather(self._pipe(reader, up_writer), self._pipe(up_reader, writer))

    async def _drain(self, reader, length: int) -> None:
        left = min(length, DRAIN_FACTOR * self.limit, DRAIN_MAX)
        try:
            while left > 0:
                chunk = await asyncio.wait_for(reader.read(min(left, 65536)), 5)
                if not chunk:
                    return
                left -= len(chunk)
        except (asyncio.TimeoutError, ConnectionError):
            return

    @staticmethod
    async def _pipe(reader, writer) -> None:
        try:
            while True:
                chunk = await reader.read(65536)
                if not chunk:
                    break
                writer.write(chunk)
                await writer.drain()
        except (ConnectionError, OSError):
            pass
        finally:
            try:
                writer.close()
            except (ConnectionError, OSError, RuntimeError):
                pass

    @staticmethod
    async def _answer(writer, status: int, detail: str, allow: bool = False) -> None:
        import http

        body = json.dumps({"detail": detail}).encode()
        reason = http.HTTPStatus(status).phrase
        head = (f"HTTP/1.1 {status} {reason}\r\nContent-Type: application/json\r\n"
                f"Content-Length: {len(body)}\r\nConnection: close\r\n"
                + ("Allow: GET\r\n" if allow else "") + "\r\n")
        try:
            writer.write(head.encode() + body)
            await writer.drain()
        except (ConnectionError, OSError):
            pass
        finally:
            writer.close()

    def stop(self) -> None:
        def close():
            if getattr(self, "server", None) is not None:
                self.server.close()
            self.loop.stop()

        if self.loop.is_running():
            self.loop.call_soon_threadsafe(close)
            self.thread.join(timeout=10)
