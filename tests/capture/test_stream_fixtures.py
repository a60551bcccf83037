"""Every recorded-stream fixture decodes to exactly the frames it should, with the right counters."""

import json

import numpy as np
import pytest

from capture import parse_bvh, read_bvh
from capture.rawcapture import read_raw_capture
from capture.recordings import bundled_dir
from capture.sources import RawFileTransport, Source
from capture.stream_layout import StreamLayout

from tests.conftest import FIXTURES

STREAMS = FIXTURES / "streams"
EXPECTED = json.loads((STREAMS / "expected.json").read_text())
COUNTERS = ("frames", "dropped", "corrupt", "resynced", "restarts", "reconnects",
            "first_index", "last_index")


def test_fixture_set_is_complete():
    assert sorted(p.name for p in STREAMS.glob("*.raw")) == sorted(EXPECTED)
    formats = {(e["format"], e["with_displacement"], e["with_reference"])
               for e in EXPECTED.values()}
    for fmt in ("binary", "binary-old", "string"):
        assert (fmt, True, False) in formats and (fmt, False, False) in formats
    assert ("binary", True, True) in formats and ("binary", False, True) in formats
    for name in ("split_every_offset", "garbage_between_frames", "truncated_last_frame",
                 "disconnect_midframe", "skipped_indices"):
        assert f"{name}.raw" in EXPECTED


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_fixture_decodes_exactly(name):
    expected = EXPECTED[name]
    transport = RawFileTransport(STREAMS / name)
    header = parse_bvh(transport.header["skeleton_bvh"], unit=None)
    source = Source(transport, StreamLayout(header.skeleton))
    frames = list(source)
    stats = source.stats()
    assert {k: stats[k] for k in COUNTERS} == {k: expected[k] for k in COUNTERS}
    recording = read_bvh(bundled_dir() / expected["recording"], unit=None)
    want = recording.motion.channels[expected["source_frames"]].astype(np.float32)
    got = np.array([source.channels(f) for f in frames]).astype(np.float32)
    np.testing.assert_array_equal(got, want)
    for f in frames:
        assert f.kind == expected["format"]
        if f.kind != "string":
            assert f.with_displacement == expected["with_displacement"]
            assert f.with_reference == expected["with_reference"]


def test_split_fixture_really_splits_at_every_offset():
    cap = read_raw_capture(STREAMS / "split_every_offset.raw")
    firsts = [len(r.data) for r in cap.records[1::2]]
    assert sorted(firsts) == list(range(1, len(firsts) + 1))
