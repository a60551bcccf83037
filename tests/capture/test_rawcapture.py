"""Raw captures: exact bytes and times, refusal to overwrite, a killed writer's file."""

import pytest

from capture.rawcapture import (
    CONNECTED,
    DATA,
    MAGIC,
    RawCaptureError,
    RawCaptureWriter,
    read_raw_capture,
)


def test_round_trip(tmp_path):
    path = tmp_path / "s.raw"
    with RawCaptureWriter(path, source="tcp://127.0.0.1:7001", time_origin=1000.0,
                          skeleton_bvh="HIERARCHY ...") as w:
        w.write(CONNECTED, 1000.5, b"connected")
        w.write(DATA, 1000.75, b"\xff\xdd\x00 bytes")
        w.write(DATA, 1001.0, b"")
    cap = read_raw_capture(path)
    assert cap.header["source"] == "tcp://127.0.0.1:7001"
    assert cap.header["skeleton_bvh"] == "HIERARCHY ..."
    assert cap.header["started_at"].startswith("1970-01-01T00:16:40")
    assert [(r.kind, r.t, r.data) for r in cap.records] == [
        (CONNECTED, 0.5, b"connected"), (DATA, 0.75, b"\xff\xdd\x00 bytes"), (DATA, 1.0, b"")]
    assert not cap.truncated
    assert path.read_bytes().startswith(MAGIC)


def test_killed_writer_leaves_a_readable_file(tmp_path):
    path = tmp_path / "s.raw"
    w = RawCaptureWriter(path, source="udp://:7002", transport="datagram", time_origin=0.0)
    for k in range(5):
        w.write(DATA, k * 0.01, bytes([k]) * 100)
    w.close()
    whole = path.read_bytes()
    path.write_bytes(whole[:-37])  # the last record cut mid-way, as by kill -9
    cap = read_raw_capture(path)
    assert cap.truncated and len(cap.records) == 4 and cap.transport == "datagram"


def test_refuses_to_overwrite(tmp_path):
    path = tmp_path / "s.raw"
    path.write_bytes(b"precious")
    with pytest.raises(RawCaptureError, match="Refusing to overwrite"):
        RawCaptureWriter(path, source="x", time_origin=0.0)
    assert path.read_bytes() == b"precious"


@pytest.mark.parametrize("content, message", [
    (b"", "expected a raw capture"),
    (b"HIERARCHY\n", "expected a raw capture"),
    (MAGIC + b"\x05\x00\x00\x00{bad", "expected a 5-byte header|JSON"),
    (MAGIC + b"\x02\x00\x00\x00[]", "header object"),
])
def test_bad_files_are_named(tmp_path, content, message):
    path = tmp_path / "bad.raw"
    path.write_bytes(content)
    with pytest.raises(RawCaptureError, match=message):
        read_raw_capture(path)


def test_listen_and_replay_say_when_the_last_record_is_cut_short(tmp_path, capsys):
    """The README's promise: a raw capture's cut-off last record is ignored and reported, by
    the commands as by the reader."""
    import json

    from capture.replay import Replay
    from studio.cli import main
    from tests.capture.test_stream_fixtures import STREAMS

    cut = tmp_path / "cut.raw"
    cut.write_bytes((STREAMS / "coalesced_reads.raw").read_bytes()[:20000])
    assert read_raw_capture(cut).truncated
    assert main(["capture", "listen", f"file:{cut}", "--skeleton",
                 "bundled:cmu_75_18_high_sit.bvh", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert any("the last record is cut short" in e for e in summary["events"])
    assert "cut short" in Replay.from_raw(cut).description
