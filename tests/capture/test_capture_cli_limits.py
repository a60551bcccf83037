"""The capture commands' limits and messages: what cannot end a reading as meant is refused at
once, a frame index stays within the header's u32, a replay served beyond this machine says so,
and a stream whose every frame was rejected says that rather than only its last event."""

import math
import time
from pathlib import Path

import pytest

from capture import read_bvh
from capture.cli import listen
from capture.neuron import encode_binary
from capture.rawcapture import DATA, RawCaptureWriter
from capture.replay import Replay, ReplayError, TcpServerSink, UdpSink
from capture.stream_layout import StreamLayout
from studio.cli import main

from ..conftest import recording

AXIS = "bundled:axis_neuron_standing_yxz.bvh"
FIXTURE = Path(__file__).parents[2] / "fixtures" / "streams" / "axis_binary_disp.raw"


def _argument_error(capsys, argv, option):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {option}:" in err
    return err


@pytest.mark.parametrize("option, value, said", [
    ("--duration", "nan", "expected a number, got 'nan'"),  # (NaN never ended a reading)
    ("--duration", "-1", "expected a number > 0, got '-1'"),
    ("--frames", "0", "expected a whole number >= 1, got '0'"),
    ("--frames", "-3", "expected a whole number >= 1, got '-3'"),
])
def test_listen_refuses_limits_that_cannot_end_it(capsys, option, value, said):
    source = f"file:{FIXTURE}"  # (a source that ends: a limit not refused cannot hang)
    err = _argument_error(capsys, ["capture", "listen", source, "--skeleton", AXIS,
                                   option, value], option)
    assert said in err


@pytest.mark.parametrize("duration, frames", [(math.nan, None), (0.0, None), (None, 0),
                                              (None, 2.5)])
def test_listen_function_refuses_the_same(duration, frames):
    end = time.monotonic() + 1.0  # (a reading that is not refused stops anyway)
    with pytest.raises(ValueError, match="Expected a (duration|whole number of frames)"):
        listen("udp://127.0.0.1:0", AXIS, duration=duration, frames=frames,
               stop=lambda: time.monotonic() > end)


@pytest.mark.parametrize("option, value, said", [
    ("--frames", "-1", "expected a whole number >= 1, got '-1'"),  # (sent one frame)
    ("--frames", "0", "expected a whole number >= 1, got '0'"),
    ("--start-index", "-1", "expected a whole number >= 0, got '-1'"),
    ("--start-index", "4294967296", "expected a whole number <= 4294967295, got '4294967296'"),
    ("--rate", "-1", "expected a number >= 0, got '-1'"),
    ("--max-datagram", "0", "expected a whole number >= 1, got '0'"),
])
def test_replay_refuses_counts_out_of_range(capsys, option, value, said):
    fast = ["--rate", "0"] + ([] if option == "--frames" else ["--frames", "3"])
    err = _argument_error(capsys, ["capture", "replay", AXIS, "--udp", "127.0.0.1:9", *fast,
                                   option, value], option)
    assert said in err


def test_replay_programme_refuses_the_same():
    path = recording("axis_neuron_standing_yxz.bvh")
    with pytest.raises(ReplayError, match=r"start index from 0 to 4294967295 \(the header.s u32\), got -1"):
        Replay.from_bvh(path, start_index=-1)
    replay = Replay.from_bvh(path, start_index=0xFFFFFFFF)  # the last u32 index is fine
    sink = UdpSink("127.0.0.1", 9)
    try:
        with pytest.raises(ReplayError, match="whole number of frames >= 1, got 0"):
            replay.run(sink, rate=0, max_frames=0)
        assert replay.run(sink, rate=0, max_frames=2).frames_sent == 2
    finally:
        sink.close()


def test_replay_served_beyond_loopback_warns():
    said = []
    sink = TcpServerSink("127.0.0.1", 0, on_event=said.append)
    sink.close()
    assert said == []
    sink = TcpServerSink("0.0.0.0", 0, on_event=said.append)
    sink.close()
    assert len(said) == 1 and said[0].startswith("warning: serving tcp://0.0.0.0:")
    assert "other machines" in said[0]


def test_no_frame_message_counts_rejected_candidates(tmp_path, capsys):
    """Every frame followed by stray bytes (no checksum: none can be confirmed): the error
    says frames came and were rejected, not only that the input ended."""
    path = recording("axis_neuron_standing_yxz.bvh")
    bvh = read_bvh(path, unit=None)
    payload = StreamLayout(bvh.skeleton).to_payload(bvh.motion.channels[:4])
    raw = tmp_path / "noisy.raw"
    t0 = time.time()
    writer = RawCaptureWriter(raw, source="tcp://127.0.0.1:7001", time_origin=t0)
    for k, values in enumerate(payload):
        writer.write(DATA, t0 + k * 0.01, encode_binary(values, frame_index=k) + b"stray!")
    writer.close()
    assert main(["capture", "listen", f"file:{raw}", "--skeleton", AXIS]) == 2
    err = capsys.readouterr().err
    assert "no frame received" in err
    assert "4 candidate frames rejected as corrupt" in err
    # a recording of the same says the same, and stores nothing
    db = tmp_path / "poses.h5"
    assert main(["capture", "record", f"file:{raw}", "--skeleton", AXIS, "--db", str(db),
                 "--take", "noisy"]) == 2
    err = capsys.readouterr().err
    assert "no frame received" in err and "4 candidate frames rejected as corrupt" in err
    assert not db.exists()
