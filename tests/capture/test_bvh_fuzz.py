"""Hostile BVH input: every case a BvhParseError naming its line, or a correct read, in budget.

The probes of issue 20 (deep nesting, glued braces, many siblings, superscript digits, huge
counts, a one-line hierarchy, CR-only files, tiny frame times) are generated here, never
committed. Each case is parsed once timed (time.perf_counter) and once under tracemalloc (peak
of Python and numpy allocations), and must stay under TIME_S and MEMORY_B. The default run uses
small sizes (a few seconds in all); `pytest -m slow` runs the full profile (100,000 levels,
siblings and braces, a 5-million-token line, a 4 MB CR-only file). A mutation fuzz test
(hypothesis) mangles a valid file and accepts only a read or a BvhParseError.
"""

import functools
import json
import math
import re
import time
import tracemalloc

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from capture import BvhParseError, parse_bvh
from capture.bvh import MAX_DEPTH, MAX_JOINTS

TIME_S = 2.0
MEMORY_B = 500 * 2**20

HEAD = "HIERARCHY\nROOT r\n{\nOFFSET 0 0 0\nCHANNELS 3 Zrotation Xrotation Yrotation\n"
TAIL = "}\nMOTION\nFrames: 1\nFrame Time: 0.01\n0 0 0\n"


def _header(frames_line: str = "Frames: 1", time_line: str = "Frame Time: 0.01",
            channels: str = "CHANNELS 1 Xrotation", data: str = "0\n") -> str:
    return (f"HIERARCHY\nROOT a\n{{\nOFFSET 0 0 0\n{channels}\n}}\nMOTION\n{frames_line}\n"
            f"{time_line}\n{data}")


def deep(n: int) -> bytes:
    joints = "".join(f"JOINT j{i}\n{{\nOFFSET 0 1 0\nCHANNELS 0\n" for i in range(n))
    return (HEAD + joints + "}\n" * n + TAIL).encode()


def siblings(n: int) -> bytes:
    joints = "".join(f"JOINT j{i}\n{{\nOFFSET 0 1 0\nCHANNELS 0\n}}\n" for i in range(n))
    return (HEAD + joints + TAIL).encode()


def one_line(n: int, own_line: bool) -> bytes:
    body = "ROOT a { OFFSET 0 0 0 CHANNELS 0 " + "JOINT b { OFFSET 0 0 0 CHANNELS 0 } " * (n // 10)
    return ("HIERARCHY" + ("\n" if own_line else " ") + body + "}\nMOTION\nFrames: 0\n"
            "Frame Time: 0.01\n").encode()


def cr_only(frames: int) -> bytes:
    rows = "".join(f"{k % 90}.5 {k % 7}.25 -{k % 13}.125\n" for k in range(frames))
    return (HEAD + TAIL.replace("Frames: 1", f"Frames: {frames + 1}") + rows).replace(
        "\n", "\r").encode()


def _lf(data: bytes) -> bytes:
    return data.replace(b"\r", b"\n")


@functools.lru_cache(maxsize=1)
def cases(size: int) -> dict[str, tuple[bytes, object]]:
    """name: (content, expectation): the line the error must name (with a message pattern), or
    'read' for a file that must read (checked by `_check_read`)."""
    glued = ("HIERARCHY\nROOT Hips" + "{" * size + "\n").encode()
    deep_line = 2 + 4 * MAX_DEPTH  # the JOINT one level too deep
    sibling_line = 1 + 5 * MAX_JOINTS  # the JOINT one too many
    return {
        "deep_nesting": (deep(size), (deep_line, r"nested at most 1000 deep")),
        "deep_at_the_limit": (deep(MAX_DEPTH - 1), "read"),
        "glued_braces": (glued, (2, r"got '\{'")),
        "glued_braces_on_own_line": (b"HIERARCHY\nROOT Hips\n" + b"{" * size + b"\n",
                                     (3, r"got '\{'")),
        "siblings": (siblings(size), (sibling_line, r"at most 10000 joints")
                     if size >= MAX_JOINTS else "read"),
        # the full profile reads the most joints allowed; the default run a tenth of them
        "siblings_at_the_limit": (siblings(MAX_JOINTS - 1 if size >= MAX_JOINTS
                                           else MAX_JOINTS // 10), "read"),
        "frames_superscript": (_header("Frames: ²").encode(), (8, r"whole number of frames")),
        "channels_superscript": (_header(channels="CHANNELS ² Xrotation Yrotation").encode(),
                                 (5, r"channel count")),
        "offset_superscript": (_header().replace("OFFSET 0 0 0", "OFFSET ² 0 0").encode(),
                               (4, r"a number in OFFSET")),
        "motion_superscript": (_header(data="²\n").encode(), (10, r"ASCII")),
        "frames_5000_digits": (_header("Frames: " + "9" * 5000).encode(), (8, r"Frames")),
        "frames_16_digits": (_header("Frames: " + "9" * 16).encode(), (8, r"at most 15 digits")),
        "channels_5000_digits": (_header(channels="CHANNELS " + "9" * 5000).encode(),
                                 (5, r"at most 6 channels")),
        "channels_0_frames_10e30": (_header("Frames: 10^30", channels="CHANNELS 0",
                                            data="").encode(), (8, r"whole number")),
        "channels_0_frames_10e14": (_header("Frames: 1" + "0" * 14, channels="CHANNELS 0",
                                            data="").encode(), (8, r"channels for the declared")),
        "frames_10e14_one_row": (_header("Frames: 1" + "0" * 14).encode(),
                                 (8, r"expected 100000000000000 frames .* got 1 lines")),
        "one_line_file": (one_line(size, own_line=False), (1, r"nothing after 'HIERARCHY'")),
        "one_line_hierarchy": (one_line(size, own_line=True), (2, r"3 numbers after OFFSET")),
        "long_name": (("HIERARCHY\nROOT " + "a" * size + " b\n").encode(),
                      (2, r"at most 256 characters")),
        "many_name_words": (("HIERARCHY\nROOT " + "a " * size + "\n").encode(),
                            (2, r"at most 256 characters")),
        "long_offset_line": (_header().replace("OFFSET 0 0 0", "OFFSET" + " 0" * size).encode(),
                             (4, r"at most 16 words after OFFSET")),
        "long_motion_line": (_header(data="0 " * size + "\n").encode(),
                             (10, rf"expected 1 values per frame .* got {size}")),
        "cr_only": (cr_only(size), "read"),
        "cr_only_truncated": (cr_only(size)[:-40], (None, r"frames|values per frame")),
        "trailing_blanks": (_header(data="0\n" + " \n" * size).encode(), "read"),
        **{f"frame_time_{t}": (_header(time_line=f"Frame Time: {t}").encode(),
                               (9, r"frame time|seconds per frame"))
           for t in ("1e-320", "1e-7", "0", "-0.01", "nan", "inf", "1e400", "3601")},
        "frame_time_1e-6": (_header(time_line="Frame Time: 1e-6").encode(), "read"),
        # values a stream's float32 or forward kinematics would overflow (1e308 was read)
        "huge_value": (_header(data="1e308\n").encode(), (10, r"within \+-1e\+09 in column 1")),
        "huge_value_digits": (_header(data="1" + "0" * 12 + "\n").encode(),
                              (10, r"within \+-1e\+09 in column 1")),
        "huge_offset": (_header().replace("OFFSET 0 0 0", "OFFSET 0 1e300 0").encode(),
                        (4, r"within \+-1e\+09 in OFFSET")),
        "largest_value": (_header(data="-1e9\n").encode(), "read"),
    }


def _parse(data: bytes):
    try:
        return parse_bvh(data, unit="m", path="fuzz.bvh")
    except BvhParseError as exc:
        return exc


def _measure(data: bytes):
    start = time.perf_counter()
    outcome = _parse(data)
    elapsed = time.perf_counter() - start
    tracemalloc.start()
    try:
        _parse(data)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    return outcome, elapsed, peak


def _check_read(name: str, data: bytes, bvh) -> None:
    assert not isinstance(bvh, BvhParseError), f"{name}: {bvh}"
    if name.startswith("cr_only"):
        lf = parse_bvh(_lf(data), unit="m")
        np.testing.assert_array_equal(bvh.motion.channels, lf.motion.channels)
    if name.startswith("deep"):
        assert bvh.skeleton.num_joints == MAX_DEPTH
        tip = bvh.world_positions()[0, -1]
        np.testing.assert_allclose(tip, [0.0, MAX_DEPTH - 1, 0.0])
    if name.startswith("siblings"):
        assert bvh.skeleton.parents[1:].tolist() == [0] * (bvh.skeleton.num_joints - 1)
    info = {"fps": bvh.motion.fps, "duration": bvh.motion.duration}
    json.dumps(info, allow_nan=False)
    assert math.isfinite(info["fps"]) and math.isfinite(info["duration"])


def _run(size: int, name: str) -> None:
    data, expected = cases(size)[name]
    outcome, elapsed, peak = _measure(data)
    if expected == "read":
        _check_read(name, data, outcome)
    else:
        line, pattern = expected
        assert isinstance(outcome, BvhParseError), f"{name}: read where an error was expected"
        assert outcome.path == "fuzz.bvh" and outcome.line is not None
        if line is not None:
            assert outcome.line == line, str(outcome)
        assert re.search(pattern, outcome.message), outcome.message
    assert elapsed < TIME_S, f"{name}: {elapsed:.2f} s"
    assert peak < MEMORY_B, f"{name}: {peak / 2**20:.0f} MB"


SMALL = 2_000


@pytest.mark.parametrize("name", sorted(cases(SMALL)))
def test_probe_small(name):
    _run(SMALL, name)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(cases(SMALL)))
def test_probe_full(name):
    _run(100_000, name)


@pytest.mark.slow
def test_one_line_hierarchy_of_five_million_tokens():
    data = one_line(5_000_000, own_line=True)
    outcome, elapsed, peak = _measure(data)
    assert isinstance(outcome, BvhParseError) and outcome.line == 2
    assert elapsed < TIME_S and peak < MEMORY_B, (elapsed, peak)


@pytest.mark.slow
def test_cr_only_file_of_four_megabytes():
    data = cr_only(250_000)
    assert len(data) > 4_000_000
    outcome, elapsed, peak = _measure(data)
    _check_read("cr_only", data, outcome)
    assert elapsed < TIME_S and peak < MEMORY_B, (elapsed, peak)


VALID = (
    "HIERARCHY\nROOT Hips\n{\n\tOFFSET 0 0 0\n\tCHANNELS 6 Xposition Yposition Zposition "
    "Zrotation Xrotation Yrotation\n\tJOINT Spine\n\t{\n\t\tOFFSET 0 10 0\n\t\tCHANNELS 3 "
    "Zrotation Xrotation Yrotation\n\t\tEnd Site\n\t\t{\n\t\t\tOFFSET 0 10 0\n\t\t}\n\t}\n}\n"
    "MOTION\nFrames: 2\nFrame Time: 0.0333333\n0 90 0 0 0 0 0 0 0\n0 90 0 10 0 0 5 0 0\n"
).encode()
PIECES = [b"{", b"}", b"\n", b"\r", b" ", b"\t", b"JOINT x", b"End", b"OFFSET", b"CHANNELS",
          b"0", b"\xc2\xb2", b"\xff", b"nan", b"9" * 30, b"MOTION", b"Frames:", b"1e-320",
          b",", b"ROOT"]


@st.composite
def mutated(draw):
    data = bytearray(VALID)
    for _ in range(draw(st.integers(1, 6))):
        at = draw(st.integers(0, len(data)))
        kind = draw(st.sampled_from(["insert", "delete", "repeat"]))
        if kind == "insert":
            data[at:at] = draw(st.sampled_from(PIECES)) * draw(st.sampled_from([1, 2, 50]))
        elif kind == "delete":
            del data[at:at + draw(st.integers(1, 20))]
        else:
            data[at:at] = data[at:at + draw(st.integers(1, 40))] * draw(st.integers(2, 200))
    return bytes(data)


@settings(deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutated())
def test_mutations_read_or_fail_with_a_line(data):
    start = time.perf_counter()
    outcome = _parse(data)
    assert time.perf_counter() - start < TIME_S
    if isinstance(outcome, BvhParseError):
        assert outcome.line is not None and outcome.line >= 1
        assert outcome.line <= data.count(b"\n") + data.count(b"\r") + 1
    else:
        channels = outcome.motion.channels
        assert channels.shape == (outcome.motion.num_frames, outcome.skeleton.num_channels)
        assert np.isfinite(channels).all()
        assert math.isfinite(outcome.motion.fps)


def test_bvh_info_of_hostile_files_is_one_line_and_json_is_valid(tmp_path, capsys):
    from solver.cli import main

    too_deep = tmp_path / "deep.bvh"
    too_deep.write_bytes(deep(MAX_DEPTH + 5))
    assert main(["bvh", "info", str(too_deep)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{too_deep}:" in err and "nested" in err
    fast = tmp_path / "fast.bvh"
    fast.write_bytes(_header(time_line="Frame Time: 1e-6").encode())
    assert main(["bvh", "info", str(fast), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["fps"] == pytest.approx(1e6)


def _report(size: int) -> None:  # pragma: no cover - a look at the figures by hand
    for name in sorted(cases(size)):
        _, elapsed, peak = _measure(cases(size)[name][0])
        print(f"{name:28s} {elapsed:6.3f} s {peak / 2**20:7.1f} MB")
