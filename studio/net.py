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
