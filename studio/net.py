"""What both servers share: which addresses count as loopback, and a request size limit."""

from __future__ import annotations

import ipaddress
import json
import socket

LOOPBACK = "127.0.0.1"
DRAIN_FACTOR, DRAIN_MAX = 4, 64 * 1024 * 1024  # bytes of a refused body still read and dropped


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


def exposure_warning(host: str, what: str) -> str | None:
    """The warning to show when a server is asked to listen beyond this machine."""
    if is_loopback(host):
        return None
    return (f"warning: the {what} listens on {host}, reachable from other machines; it has no "
            "authentication, and anyone who reaches it can run fits and read the pose library")


class BodyLimit:
    """ASGI middleware: a request whose body is larger than `limit` bytes gets 413 (checked on
    Content-Length when given, and on the bytes as they arrive)."""

    def __init__(self, app, limit: int):
        self.app = app
        self.limit = int(limit)

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        declared = dict(scope.get("headers") or ()).get(b"content-length")
        if declared is not None:
            try:
                size = int(declared)
            except ValueError:
                return await _reply(send, 400, "Content-Length is not a number")
            if size > self.limit:
                await self._drain(receive, 0)
                return await _reply(send, 413, self._message(size))
        seen = 0
        refused = False
        started = False

        async def limited_receive():
            # past the limit: answer 413 here and tell the app the client has gone
            nonlocal seen, refused
            if refused:
                return {"type": "http.disconnect"}
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > self.limit:
                    refused = True
                    if not started:
                        if message.get("more_body", False):
                            await self._drain(receive, seen)
                        await _reply(send, 413, self._message(seen))
                    return {"type": "http.disconnect"}
            return message

        async def guarded_send(message):
            nonlocal started
            if refused:
                return  # the 413 went out already
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        await self.app(scope, limited_receive, guarded_send)

    async def _drain(self, receive, seen: int) -> None:
        """Reads and drops the rest of a refused body, up to DRAIN_FACTOR times the limit:
        closing on unread bytes resets the connection, and the client may never see the 413.
        A body larger still is cut off."""
        cap = min(DRAIN_FACTOR * self.limit, DRAIN_MAX)
        while seen <= cap:
            message = await receive()
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
    websocket), one with a body over `limit` bytes gets 413, any other with a body 405, and a
    request head over 64 KiB 431. The first request of a connection is the one looked at: later
    requests on a kept-alive connection reach viser, which closes on anything but GET. Runs its
    own event loop in a thread; `port` is the one bound."""

    HEAD_LIMIT = 64 * 1024

    def __init__(self, host: str, port: int, backend_port: int, limit: int):
        import asyncio
        import threading

        self.backend_port, self.limit = backend_port, int(limit)
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
        import asyncio

        try:
            head = await reader.readuntil(b"\r\n\r\n")
        except asyncio.LimitOverrunError:
            return await self._answer(writer, 431, "Request head larger than 64 KiB")
        except (asyncio.IncompleteReadError, ConnectionError):
            writer.close()
            return
        lines = head.decode("latin-1").split("\r\n")
        method = lines[0].split(" ", 1)[0]
        headers = {}
        for line in lines[1:]:
            name, _, value = line.partition(":")
            headers[name.strip().lower()] = value.strip()
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
        import asyncio

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
