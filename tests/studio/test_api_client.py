"""`sitrelax serve` as a client written elsewhere meets it: a client that gives up and closes its
connection mid-fit stops the work done for it, and a body sent as another content type is told
so by name."""

from __future__ import annotations

import asyncio
import http.client
import json
import socket
import threading
import time
import tomllib

import pytest

from solver.bench import _example_path
from studio.api import ApiThread
from studio.net import BodyLimit

SINGLE = tomllib.loads(_example_path("single_seated").read_text())
HIGH_SIT = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"


@pytest.fixture(scope="module")
def api():
    server = ApiThread(None, time_limit=30.0)
    yield server
    server.stop()


def _post_and_hang_up(api, path: str, body: dict, after: float) -> float:
    """Sends `body` to `path`, closes the connection `after` seconds later without reading the
    answer; the time.monotonic() it closed at."""
    data = json.dumps(body).encode()
    sock = socket.create_connection((api.host, api.port), timeout=10)
    sock.sendall(f"POST {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json"
                 f"\r\nContent-Length: {len(data)}\r\n\r\n".encode() + data)
    time.sleep(after)
    sock.close()
    return time.monotonic()


class _CancelWatch:
    """A fit that takes as long as it is let (until its `cancel` says so, 8 s at most), noting
    when it was cancelled."""

    def __init__(self):
        self.started = threading.Event()
        self.cancelled_at: float | None = None

    def __call__(self, scenario, people, progress=None, *, warm=None, cancel=None,
                 iterates=None):
        self.started.set()
        end = time.monotonic() + 8.0
        while time.monotonic() < end:
            if cancel():
                self.cancelled_at = time.monotonic()
                break
            time.sleep(0.01)


@pytest.mark.parametrize("path", ["/api/fit", "/api/relax"])
def test_a_client_that_hangs_up_mid_fit_cancels_the_fit(api, path, monkeypatch):
    """Before: the fit ran on for nobody until the time limit (30 s here, 60 by default)."""
    import solver.scene.run

    fake = _CancelWatch()
    monkeypatch.setattr(solver.scene.run, "fit_people", fake)
    body = SINGLE if path == "/api/fit" else {"scenario": SINGLE, "index": 0}
    closed = _post_and_hang_up(api, path, body, after=0.5)
    assert fake.started.is_set()
    deadline = time.monotonic() + 8.5
    while fake.cancelled_at is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert fake.cancelled_at is not None, "the fit was not cancelled"
    assert fake.cancelled_at - closed < 1.0
    # the server serves on
    conn = http.client.HTTPConnection(api.host, api.port, timeout=10)
    conn.request("GET", "/api/health")
    assert conn.getresponse().status == 200


@pytest.mark.slow  # (3.5-7.5 s: the default run stays within its time)
def test_an_evaluation_stops_at_the_next_person_once_its_client_hangs_up(api, monkeypatch):
    import solver.contact.evaluate

    evaluated = []
    real = solver.contact.evaluate.evaluate_person

    def slow_evaluate(*args, **kwargs):
        evaluated.append(time.monotonic())
        time.sleep(1.0)
        return real(*args, **kwargs)

    monkeypatch.setattr(solver.contact.evaluate, "evaluate_person", slow_evaluate)
    quad = [[-0.3, 0.42, -0.4], [0.3, 0.42, -0.4], [0.3, 0.42, 0.4], [-0.3, 0.42, 0.4]]
    body = {"vertices": quad, "faces": [[0, 3, 2, 1]], "person": [{"pose": HIGH_SIT}] * 4}
    _post_and_hang_up(api, "/api/evaluate", body, after=0.5)
    time.sleep(3.0)  # four people would take 4 s and more
    assert len(evaluated) <= 2, evaluated  # (the one under way when it hung up)


@pytest.mark.slow
def test_a_real_fit_stops_using_the_cpu_once_its_client_hangs_up(api):
    """A fit of several seconds (a fine grid, no tolerance) given up after a second: the server
    stops computing (before: about a second of CPU for every second after, to the limit)."""
    import resource

    heavy = json.loads(json.dumps(SINGLE))
    heavy["surface"].update(grid={"size": [0.5, 0.6], "resolution": [48, 36], "height": 0.42},
                            max_iterations=10, tolerance=0.0)
    _post_and_hang_up(api, "/api/fit", heavy, after=1.0)
    time.sleep(1.5)  # (the stage it was in ends)
    before = resource.getrusage(resource.RUSAGE_SELF)
    time.sleep(2.0)
    after = resource.getrusage(resource.RUSAGE_SELF)
    used = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    assert used < 0.5, f"{used:.2f} s of CPU in 2 s after the client had gone"


def test_the_body_limit_does_not_time_out_the_wait_for_a_client_leaving():
    """Once the body is whole, the app's wait for the client to go (its work still running) is
    no body pause: no 408 is sent, and the disconnect reaches the app when it comes."""
    sent, got = [], []

    async def app(scope, receive, send):
        while (await receive()).get("more_body"):
            pass
        began = time.monotonic()
        got.append(((await receive())["type"], time.monotonic() - began))

    async def main():
        messages = [{"type": "http.request", "body": b"{}", "more_body": False}]

        async def receive():
            if messages:
                return messages.pop(0)
            await asyncio.sleep(0.5)  # the client leaves later than the body timeout
            return {"type": "http.disconnect"}

        async def send(message):
            sent.append(message)

        scope = {"type": "http", "headers": [(b"content-length", b"2")]}
        await BodyLimit(app, limit=100, timeout=0.1)(scope, receive, send)

    asyncio.run(main())
    assert not sent, sent
    assert got and got[0][0] == "http.disconnect" and got[0][1] >= 0.4, got


def _raw_post(api, path: str, data: bytes, content_type: str | None):
    conn = http.client.HTTPConnection(api.host, api.port, timeout=30)
    conn.request("POST", path, body=data,
                 headers={} if content_type is None else {"Content-Type": content_type})
    response = conn.getresponse()
    payload = response.read()
    conn.close()
    return response.status, json.loads(payload)


@pytest.mark.parametrize("content_type, shown", [
    (None, "got none"),  # (requests.post(url, data=text) sends none)
    ("text/plain", "got 'text/plain'"),
    ("application/x-www-form-urlencoded", "x-www-form-urlencoded"),  # urllib's default
])
@pytest.mark.parametrize("path", ["/api/fit", "/api/body", "/api/evaluate", "/api/relax"])
def test_a_json_body_sent_as_another_content_type_is_told_so(api, path, content_type, shown):
    """Before: 422 "Input should be a valid dictionary or object to extract fields from" for a
    body that is one."""
    status, reply = _raw_post(api, path, json.dumps(SINGLE).encode(), content_type)
    assert status == 415, reply
    assert "Content-Type: application/json" in reply["detail"] and shown in reply["detail"]


def test_json_content_types_are_read_and_other_malformed_bodies_stay_422(api):
    body = json.dumps({"person": {"pose": "bvh:bundled:nope.bvh#frame=1"}}).encode()
    for kind in ("application/json", "application/json; charset=utf-8",
                 "Application/JSON", "application/vnd.sitrelax+json"):
        status, reply = _raw_post(api, "/api/body", body, kind)
        assert status == 404 and "nope.bvh" in json.dumps(reply), (kind, reply)
    status, reply = _raw_post(api, "/api/body", b"[]", "application/json")
    assert status == 422 and reply["detail"][0]["loc"] == ["body"]
    status, reply = _raw_post(api, "/api/body", b"", None)  # no body at all: missing
    assert status == 422 and reply["detail"][0]["type"] == "missing"


def _raw_exchange(api, data: bytes) -> bytes:
    sock = socket.create_connection((api.host, api.port), timeout=10)
    sock.sendall(data)
    answer = b""
    while chunk := sock.recv(65536):
        answer += chunk
    sock.close()
    return answer


@pytest.mark.parametrize("head", [
    b"POST /api/fit HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: abc\r\n\r\n",
    b"POST /api/fit HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: -5\r\n\r\n",
    b"GET /api/health HTTP/1.1\r\nHost: 127.0.0.1\r\nHost: evil.example\r\n\r\n",
    b"NOT HTTP AT ALL\r\n\r\n",
    b"POST /api/fit HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
    b"Transfer-Encoding: chunked\r\n\r\nZZ\r\nabc\r\n",
])
def test_bytes_that_are_no_http_request_get_a_json_400(api, head):
    """Before: uvicorn's plain-text "Invalid HTTP request received." (no JSON to read)."""
    answer = _raw_exchange(api, head)
    status_line, _, rest = answer.partition(b"\r\n")
    headers, _, body = rest.partition(b"\r\n\r\n")
    assert status_line.startswith(b"HTTP/1.1 400"), answer[:200]
    assert b"content-type: application/json" in headers.lower()
    assert "Not a valid HTTP/1.1 request" in json.loads(body)["detail"]
