"""Several avatars on one stream (Axis broadcasts one frame per avatar when several people wear
suits): the receiver keeps them apart. The sender is the independent one written from the
wire-format reference in `test_stream_independent_sender`."""

import json
import subprocess
import sys

import numpy as np
import pytest

from capture.cli import listen
from capture.neuron import decode_all

from .test_stream_independent_sender import (COUNTS, SKELETON, binary_frame, payloads,
                                             serve_tcp, string_frame)

NAMES = ("Avatar00", "Avatar01")


def interleaved_binary(n=10, start=100, seed=0):
    """Two avatars' frames, one of each per sample, both counting from `start`; and what each
    sent: {avatar index: (n, 354) values}."""
    sent = {a: payloads(n, 354, seed=seed + a) for a in (0, 1)}
    stream = b"".join(binary_frame(sent[a][k], start + k, avatar=a, name=NAMES[a])
                      for k in range(n) for a in (0, 1))
    return stream, sent


def test_interleaved_avatars_are_neither_restarts_nor_drops():
    stream, sent = interleaved_binary()
    frames, stats = decode_all([stream[i:i + 999] for i in range(0, len(stream), 999)],
                               counts=COUNTS)
    assert len(frames) == 20
    assert (stats.restarts, stats.dropped, stats.damaged_index, stats.corrupt) == (0, 0, 0, 0)
    per = {(a["index"], a["name"]): a for a in stats.avatar_dicts()}
    assert set(per) == {(0, "Avatar00"), (1, "Avatar01")}
    for a in per.values():
        assert (a["frames"], a["first_index"], a["last_index"], a["dropped"],
                a["restarts"]) == (10, 100, 109, 0, 0)


def test_a_gap_in_one_avatar_is_its_own():
    stream, _ = interleaved_binary(n=6)
    frames, _ = decode_all(stream, counts=COUNTS)
    # drop avatar 1's frame 103: one frame missed by that avatar alone
    kept = b"".join(binary_frame(f.values, f.frame_index, avatar=f.avatar_index,
                                 name=f.avatar_name) for f in frames
                    if not (f.avatar_index == 1 and f.frame_index == 103))
    _, stats = decode_all(kept, counts=COUNTS)
    per = {a["name"]: a for a in stats.avatar_dicts()}
    assert per["Avatar00"]["dropped"] == 0 and per["Avatar01"]["dropped"] == 1
    assert stats.dropped == 1 and stats.restarts == 0


def test_stream_totals_are_the_sums_of_the_avatars_counters_and_kept_nowhere_else():
    """A gap and a restart in avatar 1, a damaged index in avatar 0: the totals are the sums
    (one count, in its avatar), and they cannot be set apart from the avatars."""
    sent = {a: payloads(8, 354, seed=30 + a) for a in (0, 1)}
    indices = {0: [100, 101, 102, 7_000_103, 104, 105, 106, 107],  # 103: a flipped bit
               1: [100, 101, 104, 105, 106, 5, 6, 7]}  # two dropped, then a restart
    stream = b"".join(binary_frame(sent[a][k], indices[a][k], avatar=a, name=NAMES[a])
                      for k in range(8) for a in (0, 1))
    frames, stats = decode_all(stream, counts=COUNTS)
    per = {a["name"]: a for a in stats.avatar_dicts()}
    assert [(per[n]["frames"], per[n]["dropped"], per[n]["restarts"],
             per[n]["damaged_index"]) for n in NAMES] == [(8, 0, 0, 1), (8, 2, 1, 0)]
    totals = stats.as_dict()
    assert {k: totals[k] for k in ("frames", "dropped", "restarts", "damaged_index")} == {
        "frames": 16, "dropped": 2, "restarts": 1, "damaged_index": 1}
    assert (stats.frames, stats.dropped, stats.restarts, stats.damaged_index) == (16, 2, 1, 1)
    for name in ("frames", "dropped", "restarts", "damaged_index"):
        with pytest.raises(AttributeError):
            setattr(stats, name, 0)


def test_split_by_avatar_keeps_each_avatars_frames_in_order():
    from capture.avatars import split_by_avatar

    sent = {a: payloads(5, 180, seed=10 + a) for a in (0, 1)}
    stream = b"".join(string_frame(sent[a][k], avatar=a, name=NAMES[a])
                      for k in range(5) for a in (0, 1))
    frames, _ = decode_all(stream, counts=COUNTS)
    groups = split_by_avatar(frames)
    assert [(k.index, k.name) for k in groups] == [(0, "Avatar00"), (1, "Avatar01")]
    for a, key in enumerate(groups):
        np.testing.assert_array_equal(np.array([f.values for f in groups[key]]), sent[a])


@pytest.mark.parametrize("text", ["Avatar01", "1", " Avatar01 "])
def test_an_avatar_is_chosen_by_name_or_index(text):
    from capture.avatars import avatar_selector

    stream, _ = interleaved_binary(n=2)
    frames, _ = decode_all(stream, counts=COUNTS)
    select = avatar_selector(text)
    assert [f.avatar_index for f in frames if select.matches(f)] == [1, 1]


def test_an_empty_avatar_is_refused():
    from capture.avatars import avatar_selector

    with pytest.raises(ValueError, match="Expected an avatar name or index, got '  '"):
        avatar_selector("  ")


def test_listen_names_the_avatars_and_counts_each():
    stream, _ = interleaved_binary(n=8)
    port = serve_tcp([stream, 0.2])
    s = listen(f"tcp://127.0.0.1:{port}", SKELETON, duration=0.6)
    assert s["frames"] == 16 and s["restarts"] == 0 and s["dropped"] == 0, s
    assert [(a["index"], a["name"], a["frames"]) for a in s["avatars"]] == [
        (0, "Avatar00", 8), (1, "Avatar01", 8)]


def test_listen_an_avatar_that_never_comes_names_those_that_did():
    from capture.avatars import AvatarNotSeenError

    stream, _ = interleaved_binary(n=4)
    port = serve_tcp([stream, 0.2])
    with pytest.raises(AvatarNotSeenError, match=r"Avatar07.*Avatar00 \(index 0, 4 frames\), "
                                                 r"Avatar01 \(index 1, 4 frames\)"):
        listen(f"tcp://127.0.0.1:{port}", SKELETON, frames=8, duration=0.6, avatar="Avatar07")


def test_cli_listen_json_and_status_name_each_avatar():
    stream, _ = interleaved_binary(n=6)
    port = serve_tcp([stream, 0.2])
    run = subprocess.run(
        [sys.executable, "-m", "studio.cli", "capture", "listen", f"tcp://127.0.0.1:{port}",
         "--skeleton", SKELETON, "--frames", "6", "--avatar", "1", "--duration", "5",
         "--json"], capture_output=True, text=True, timeout=30)
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert summary["frames"] == 6 and summary["avatar"] == "1", summary
    assert [(a["name"], a["frames"], a["kept"]) for a in summary["avatars"]] == [
        ("Avatar00", 6, False), ("Avatar01", 6, True)]


def test_a_stream_of_ever_new_avatars_keeps_its_counters_bounded():
    """A stream (hostile or broken) whose every frame names another avatar: past MAX_AVATARS
    the frames are corrupt, so the per-avatar counters do not grow without end."""
    from capture.neuron import MAX_AVATARS

    values = payloads(MAX_AVATARS + 6, 354, seed=3)
    stream = b"".join(binary_frame(values[k], 7, avatar=k, name=f"A{k}")
                      for k in range(MAX_AVATARS + 6))
    frames, stats = decode_all([stream], counts=COUNTS)
    assert len(frames) == MAX_AVATARS and len(stats.avatars) == MAX_AVATARS
    assert stats.corrupt == 6
