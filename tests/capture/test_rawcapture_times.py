"""Raw captures with times that are not finite or not plausible (a NaN or inf record time, times
1e300 s apart, a NaN time origin) are refused, naming the file and the record, before anything
of them is listened to, replayed or recorded; the statistics never report NaN or inf."""

import json
import math
import re
import struct
import subprocess
import sys

import numpy as np
import pytest

from capture.monitor import StreamMonitor, sender_timing
from capture.neuron import NeuronFrame, encode_binary
from capture.rawcapture import (
    DATA,
    MAGIC,
    RawCaptureError,
    RawCaptureWriter,
    check_raw_capture,
    raw_header,
    read_raw_capture,
)
from capture.replay import Replay
from capture.sources import RawFileTransport

AXIS = "axis_neuron_standing_yxz.bvh"
NAN, INF = math.nan, math.inf
DAY = 86400.0
_RECORD = struct.Struct("<BdI")  # the README's record head: kind u8, t f64, length u32


def _frame(k: int) -> bytes:
    return encode_binary(np.zeros(354, np.float32), frame_index=k)  # the Axis skeleton's size


def _raw(path, times, origin=1000.0, cut=0):
    """A raw capture of one Axis frame per time, written byte by byte (no writer would write
    these times); `cut` bytes off its end."""
    header = json.dumps({"source": "test", "transport": "stream", "time_origin": origin,
                         "started_at": "1970-01-01T00:16:40+00:00"}).encode()
    body = b"".join(_RECORD.pack(DATA, t, len(_frame(k))) + _frame(k)
                    for k, t in enumerate(times))
    path.write_bytes(MAGIC + struct.pack("<I", len(header)) + header + body[:len(body) - cut])
    return path


BAD_TIMES = [
    ([0.0, 0.01, 0.02, NAN, 0.04], r"record 3 .*expected a finite time.*got nan"),
    ([0.0, INF, 0.02], r"record 1 .*expected a finite time.*got inf"),
    ([-INF, 0.01], r"record 0 .*expected a finite time.*got -inf"),
    ([1e300 * (k + 1) for k in range(3)], r"record 0 .*expected a time within"),
    ([0.0, 0.01, 1e300], r"record 2 .*expected a time within"),
    ([0.0, 0.01, 40 * DAY], r"record 2 .*at most 30 days after"),
    ([5000.0, 5000.01, 5000.01 - 2 * DAY], r"record 2 .*at most 1 day before"),
]


@pytest.mark.parametrize("times, message", BAD_TIMES)
def test_reader_refuses_bad_record_times_naming_file_and_record(tmp_path, times, message):
    path = _raw(tmp_path / "bad.raw", times)
    named = re.escape(str(path)) + ": " + message
    with pytest.raises(RawCaptureError, match=named):
        read_raw_capture(path)
    with pytest.raises(RawCaptureError, match=named):
        check_raw_capture(path)
    with pytest.raises(RawCaptureError, match=named):  # before a record is delivered
        RawFileTransport(path)
    with pytest.raises(RawCaptureError, match=named):
        Replay.from_raw(path)


def test_plausible_times_are_kept(tmp_path):
    """A clock set back a little, an hour without data, and a first record far before the
    time origin (a capture of a replayed capture keeps the replayed receive times)."""
    times = [-1.7e9, -1.7e9 + 0.01, -1.7e9 + 0.005, -1.7e9 + 3600, -1.7e9 + 3599]
    path = _raw(tmp_path / "ok.raw", times)
    assert [r.t for r in read_raw_capture(path).records] == times
    assert check_raw_capture(path)[1:] == (5, False)
    replay = Replay.from_raw(path)
    assert replay.duration > 3600 and math.isfinite(replay.duration)


@pytest.mark.parametrize("origin", [NAN, INF, -INF, 1e300, "yesterday", True, None])
def test_reader_refuses_a_time_origin_that_is_not_a_finite_unix_time(tmp_path, origin):
    path = _raw(tmp_path / "bad.raw", [0.0, 0.01], origin=origin)
    named = re.escape(str(path)) + ": expected a finite Unix time as the header's time_origin"
    for read in (raw_header, read_raw_capture, RawFileTransport, Replay.from_raw):
        with pytest.raises(RawCaptureError, match=named):
            read(path)


def test_writer_refuses_what_the_reader_would(tmp_path):
    path = tmp_path / "s.raw"
    with pytest.raises(RawCaptureError, match="time origin, got nan"):
        RawCaptureWriter(path, source="x", time_origin=NAN)
    assert not path.exists()
    with RawCaptureWriter(path, source="x", time_origin=1000.0) as w:
        w.write(DATA, 1000.5, b"kept")
        with pytest.raises(RawCaptureError, match="finite record time.*got inf"):
            w.write(DATA, INF, b"lost")
    assert [r.data for r in read_raw_capture(path).records] == [b"kept"]


def test_a_cut_off_last_record_is_ignored_whatever_its_time(tmp_path, capsys):
    """The README's promise holds: the last record cut short is ignored and reported, even
    when its time is damaged too (it is never used)."""
    from studio.cli import main

    path = _raw(tmp_path / "cut.raw", [0.0, 0.01, NAN], cut=10)
    cap = read_raw_capture(path)
    assert cap.truncated and [r.t for r in cap.records] == [0.0, 0.01]
    assert check_raw_capture(path)[1:] == (2, True)
    assert main(["capture", "listen", f"file:{path}", "--skeleton", f"bundled:{AXIS}",
                 "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["frames"] == 2 and summary["fps"] == pytest.approx(100.0)
    assert any("the last record is cut short" in e for e in summary["events"])


CAPTURES = {  # the reviewer's captures: every time NaN, one time inf, times 1e300 apart
    "nan": ([NAN] * 5, 1000.0, "record 0 .*got nan"),
    "one-inf": ([0.0, 0.01, INF, 0.03], 1000.0, "record 2 .*got inf"),
    "1e300": ([1e300 * (k + 1) for k in range(5)], 1000.0, "record 0 .*within"),
    "nan-origin": ([0.0, 0.01, 0.02], NAN, "time_origin, got nan"),
}


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("capture", sorted(CAPTURES))
@pytest.mark.parametrize("command", ["listen", "replay", "record"])
def test_commands_stop_with_one_line_before_using_a_bad_capture(tmp_path, capsys, command,
                                                                 capture):
    from studio.cli import main

    times, origin, message = CAPTURES[capture]
    path = _raw(tmp_path / "bad.raw", times, origin=origin)
    args = {"listen": ["listen", f"file:{path}", "--skeleton", f"bundled:{AXIS}"],
            "replay": ["replay", str(path), "--tcp", "127.0.0.1:0"],
            "record": ["record", f"file:{path}", "--db", str(tmp_path / "lib.h5"), "--take",
                       "x", "--skeleton", f"bundled:{AXIS}"]}[command]
    if command == "replay":  # (in a process of its own: a replay that waits forever fails)
        run = subprocess.run([sys.executable, "-m", "solver.cli", "capture", *args],
                             capture_output=True, text=True, timeout=60)
        status, out, err = run.returncode, run.stdout, run.stderr
    else:
        status = main(["capture", *args])
        out, err = capsys.readouterr()
    assert status == 2
    assert out == ""  # nothing listened to, sent or recorded
    assert re.fullmatch(f"sitrelax: error: {re.escape(str(path))}: .*{message}.*\n", err), err
    assert not (tmp_path / "lib.h5").exists()


def _frames(times, indices=None):
    indices = indices if indices is not None else range(len(times))
    return [NeuronFrame(np.zeros(3, np.float32), k, 0, "A", True, False, "binary", t)
            for k, t in zip(indices, times)]


def _finite_or_none(summary):
    json.dumps(summary, allow_nan=False)  # valid JSON
    for key in ("fps", "duration_s", "latency_ms", "latency_max_ms"):
        assert summary[key] is None or math.isfinite(summary[key]), (key, summary)


@pytest.mark.filterwarnings("error")  # no RuntimeWarning leaks either
def test_monitor_leaves_out_times_that_are_not_finite():
    monitor = StreamMonitor()
    monitor.add(_frames([NAN, 10.0, INF, 10.5, -INF, 11.0, None]))
    summary = monitor.summary({})
    _finite_or_none(summary)
    assert monitor.count == 7
    assert summary["fps"] == pytest.approx(2.0) and summary["duration_s"] == 1.0
    assert summary["latency_ms"] is not None


@pytest.mark.filterwarnings("error")
def test_monitor_reports_none_for_figures_it_cannot_compute():
    monitor = StreamMonitor()  # nothing received
    summary = monitor.summary({})
    _finite_or_none(summary)
    assert summary["fps"] is None and summary["duration_s"] is None
    monitor.add(_frames([5.0, 5.0]))  # two frames, no time between them
    summary = monitor.summary({})
    _finite_or_none(summary)
    assert summary["fps"] is None and summary["duration_s"] == 0.0
    # the local clock set back while frames came: the span stays the real one
    monitor = StreamMonitor()
    monitor.add(_frames([100.0, 100.01, 99.0, 99.01]))
    assert monitor.fps() == pytest.approx(3 / 1.01) and monitor.summary({})["duration_s"] > 0
    # times so far apart that the fit overflows: no latency rather than inf
    monitor = StreamMonitor()
    monitor.add(_frames([0.0, 1e300, -1e300, 1.7e308], [0, 1, 2, 3]))
    _finite_or_none(monitor.summary({}))


@pytest.mark.filterwarnings("error")
def test_sender_timing_refuses_non_finite_times_and_never_returns_them():
    with pytest.raises(ValueError, match="finite receive times, got nan at frame 2"):
        sender_timing([0, 1, 2], [0.0, 0.01, NAN])
    period, delay = sender_timing([0, 1, 2, 3], [0.0, 1e300, -1e300, 1.7e308])
    assert period is None and np.all(np.isfinite(delay))


def test_listen_text_says_n_a_for_a_duration_it_cannot_compute(tmp_path, capsys):
    from studio.cli import main

    empty = tmp_path / "empty.raw"
    RawCaptureWriter(empty, source="test", time_origin=1000.0).close()
    assert main(["capture", "listen", f"file:{empty}", "--skeleton", f"bundled:{AXIS}"]) == 2
    out = capsys.readouterr().out
    assert "fps         - over n/a" in out and "nan" not in out
