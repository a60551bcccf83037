"""The Perception Neuron codec: hand-built frames, layouts, and damage it must survive."""

import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from capture import parse_bvh
from capture.neuron import (
    MAX_DATA_COUNT,
    TOKEN,
    NeuronStreamError,
    StreamDecoder,
    decode_all,
    encode_binary,
    encode_frame,
    encode_string,
)
from capture.stream_layout import LayoutMismatchError, StreamLayout

from .test_bvh_format import SMALL


def test_current_header_bytes_by_hand():
    blob = encode_binary(np.array([1.5, -2.0], dtype=np.float32), frame_index=0x01020304,
                         avatar_index=7, avatar_name="Chair", with_displacement=True,
                         with_reference=False)
    assert len(blob) == 64 + 8
    assert blob[0:2] == b"\xff\xdd" and blob[62:64] == b"\xff\xee"
    assert blob[2:6] == bytes([0, 0, 1, 1])  # data version 1.1.0.0
    assert struct.unpack_from("<H", blob, 6)[0] == 2
    assert blob[8] == 1 and blob[9] == 0
    assert struct.unpack_from("<I", blob, 10)[0] == 7
    assert blob[14:19] == b"Chair" and blob[19:46] == bytes(27)
    assert struct.unpack_from("<I", blob, 46)[0] == 0x01020304
    assert struct.unpack_from("<2f", blob, 64) == (1.5, -2.0)


def test_old_header_bytes_by_hand():
    blob = encode_binary(np.ones(3, dtype=np.float32), avatar_index=2, old_header=True,
                         with_displacement=False, with_reference=True)
    assert blob[2:6] == bytes([0, 0, 0, 1])
    assert struct.unpack_from("<5I", blob, 6) == (3, 0, 1, 2, struct.unpack_from("<I", blob, 22)[0])
    assert blob[22:30] == b"Avatar00"
    (frame,), stats = decode_all(blob)
    assert frame.kind == "binary-old" and frame.frame_index is None
    assert frame.with_reference and not frame.with_displacement and frame.avatar_index == 2


def test_string_frame_by_hand():
    (frame,), _ = decode_all(b"0 Avatar00 1.5 -2 3e1 ||\r\n")
    assert frame.kind == "string" and frame.avatar_name == "Avatar00"
    np.testing.assert_array_equal(frame.values, np.float32([1.5, -2.0, 30.0]))
    blob = encode_string(np.float32([0.1, 123.456]), avatar_index=3, avatar_name="Seat")
    assert blob == b"3 Seat 0.100000001 123.456001 ||\r\n"
    (again,), _ = decode_all(blob)
    np.testing.assert_array_equal(again.values, np.float32([0.1, 123.456]))


def test_impossible_data_count_is_not_allocated():
    head = bytearray(encode_binary(np.ones(2, dtype=np.float32)))[:64]
    head[6:8] = (MAX_DATA_COUNT + 1).to_bytes(2, "little")
    frames, stats = decode_all(bytes(head) + b"\0" * 100)
    assert frames == [] and stats.corrupt == 1
    with pytest.raises(NeuronStreamError, match="1 to 4096 values"):
        encode_binary(np.ones(MAX_DATA_COUNT + 1))
    with pytest.raises(NeuronStreamError, match="at most 32 bytes"):
        encode_binary(np.ones(2), avatar_name="x" * 33)


def test_frame_index_gaps_and_wraparound():
    values = np.ones(4, dtype=np.float32)
    blob = b"".join(encode_binary(values, frame_index=i)
                    for i in (0xFFFFFFFE, 0xFFFFFFFF, 0, 3, 4))
    frames, stats = decode_all(blob)
    assert [f.frame_index for f in frames] == [0xFFFFFFFE, 0xFFFFFFFF, 0, 3, 4]
    assert stats.dropped == 2 and stats.restarts == 0 and stats.gaps == [(0, 3)]


# -- layouts ------------------------------------------------------------------------------


def _small():
    return parse_bvh(SMALL, unit="cm")


def test_layout_sizes_for_the_59_bone_skeleton(axis_standing):
    from capture import read_bvh

    layout = StreamLayout(read_bvh(axis_standing).skeleton)
    assert layout.counts() == {(True, False): 354, (False, False): 180,
                               (True, True): 360, (False, True): 186}


def test_layout_maps_by_hand():
    bvh = _small()  # Hips: pos + ZXY, Spine: ZXY with offset (0, 10, 0)
    layout = StreamLayout(bvh.skeleton)
    # with displacement and reference: 6 reference floats, then (pos, rot) per bone
    values = np.arange(6 + 12, dtype=np.float32)
    ch = layout.to_channels(values, True, True)
    np.testing.assert_array_equal(ch, [6, 7, 8, 9, 10, 11, 15, 16, 17])
    # without displacement: hips position, then rotations per bone
    values = np.arange(3 + 6, dtype=np.float32)
    np.testing.assert_array_equal(layout.to_channels(values, False, False), np.arange(9))
    # the inverse fills bone positions from the offsets
    payload = layout.to_payload(bvh.motion.channels, True, False)
    np.testing.assert_array_equal(payload[1, 6:9], [0, 10, 0])
    np.testing.assert_allclose(layout.to_channels(payload, True, False), bvh.motion.channels)


def test_layout_mismatch_is_a_clear_error():
    layout = StreamLayout(_small().skeleton)
    with pytest.raises(LayoutMismatchError, match=r"2-joint skeleton header .* got 7 floats"):
        layout.to_channels(np.zeros(7), True, False)
    with pytest.raises(LayoutMismatchError, match="three rotation channels"):
        from capture import Skeleton

        StreamLayout(Skeleton(("a",), [-1], [[0, 0, 0]], (("Xrotation",),)))


def test_six_channel_header_gets_offsets_from_frames_without_displacement():
    from capture import Skeleton

    sk = _small().skeleton
    six = Skeleton(sk.names, sk.parents, sk.offsets,
                   tuple(("Xposition", "Yposition", "Zposition", "Yrotation", "Xrotation",
                          "Zrotation") for _ in sk.names), sk.end_sites, sk.end_site_parents)
    layout = StreamLayout(six)
    ch = layout.to_channels(np.arange(9, dtype=np.float32), False, False)
    np.testing.assert_array_equal(ch, [0, 1, 2, 3, 4, 5, 0, 10, 0, 6, 7, 8])


# -- damage -------------------------------------------------------------------------------

OTHER = np.ones(9, dtype=np.float32)  # another sender's frame, interleaved
COUNTS = {(False, False): 9, (False, True): 15, (True, False): 12, (True, True): 18}


def _frames(n, seed):
    rng = np.random.default_rng(seed)
    return [rng.normal(scale=90, size=9).astype(np.float32) for _ in range(n)]


def _encode(frames, fmt="binary"):
    return [encode_frame(v, fmt, frame_index=100 + i, with_displacement=False,
                         avatar_name="Seat") for i, v in enumerate(frames)]


def _same(frame, values, index):
    return frame.frame_index == index and np.array_equal(frame.values, values)


damage = st.lists(
    st.tuples(
        st.sampled_from(["garbage", "cut", "header_flip", "interleave", "insert",
                         "cut_long_tail"]),
        st.integers(0, 10**6), st.binary(min_size=1, max_size=80), st.integers(0, 10**6),
    ),
    max_size=4,
)


def _check_damage(n, seed, ops, splits, strict):
    """Damages n encoded frames by `ops`, decodes them in `splits` pieces and checks that no
    frame is invented, none comes out twice, none differs from what was sent where the damage
    left it detectable, and every intact, confirmed frame comes out."""
    values = _frames(n, seed)
    blobs = _encode(values)
    damaged = set()
    shortened = set()  # frames cut short at some point
    recounted = set()  # frames whose DataCount took a flipped bit, with no skeleton to check it
    # floats in front of the first payload byte any op changed, per frame damaged there
    untouched = {}
    prefix = [b""] * n  # stray bytes in front of each frame
    body = [bytearray(b) for b in blobs]
    interleaved = 0  # frames of the other sender, 7, 8, ..., put in front of ours in part

    def touch(k, at):
        untouched[k] = min(untouched.get(k, 9), max(0, (at - 64) // 4))

    for op, where, data, param in ops:
        k = where % n
        if op == "garbage":
            prefix[k] = data + prefix[k]
        elif op == "cut":
            cut = param % len(blobs[k])
            del body[k][cut:]
            damaged.add(k)
            shortened.add(k)
            touch(k, cut)
        elif op == "insert":
            # stray bytes inside the payload: the values after them would come out shifted
            at = 64 + param % (len(blobs[k]) - 64)
            body[k][at:at] = (data * 4)[:4]
            damaged.add(k)
            touch(k, at)
        elif op == "cut_long_tail":
            # cut short, then more stray bytes than it lost (fewer or as many slip through:
            # the format has no checksum)
            cut = 64 + param % (len(blobs[k]) - 64)
            lost = len(body[k]) - cut
            tail = (data * (lost // len(data) + 2))[:lost + 1 + param % 7]
            body[k][cut:] = tail.replace(b"\xff\xdd", b"\xfe\xdd")
            damaged.add(k)
            touch(k, cut)
        elif op == "header_flip":
            # a flipped bit in the framing fields: token, version, count, flags or footer
            # (without a paired skeleton nothing tells a flipped flag from a true one)
            fields = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 62, 63] if strict else [0, 1, 2, 3, 4, 5, 6,
                                                                              7, 62, 63]
            pos = fields[param % len(fields)]
            if pos < len(body[k]):
                body[k][pos] ^= 1 << (param // 12 % 8)
                damaged.add(k)
                if pos in (6, 7) and not strict:
                    recounted.add(k)
        else:  # interleave: part of another avatar's next frame lands in front of this one
            index = 7 + interleaved
            interleaved += 1
            other = encode_binary(OTHER, frame_index=index, with_displacement=False)
            part = 1 + param % (len(other) - 1)
            prefix[k] = other[:part] + prefix[k]
            touch(index - 100, part)
            shortened.add(index - 100)
    # A frame cut short and followed by exactly as many stray bytes as it lost looks whole (the
    # format has no checksum): only its header and the values no op changed still hold. That
    # includes a cut made up for by stray bytes inserted or appended to the same frame: those
    # can restore its length exactly (cut to 99 bytes, then 36 stray bytes after the header).
    # So does a frame whose DataCount took a flipped bit, without a skeleton to give the count,
    # when stray bytes or a cut make its payload that long (9 -> 11 values, then 8 stray bytes
    # after the header: 11 values, the first two stray).
    shortened |= recounted & set(untouched)
    kept_floats = {k: untouched[k] for k in shortened}
    pieces = [p + bytes(b) for p, b in zip(prefix, body)]
    stream = b"".join(pieces)
    cuts = sorted({s % (len(stream) + 1) for s in splits})
    chunks = [stream[a:b] for a, b in zip([0] + cuts, cuts + [len(stream)])]
    out, stats = decode_all(chunks, counts=COUNTS if strict else None)
    sent = {100 + i: v for i, v in enumerate(values)}
    for j in range(interleaved):
        sent[7 + j] = OTHER  # the interleaved frames were sent too, if only in part
    for frame in out:
        assert frame.frame_index in sent, frame
        k = frame.frame_index - 100
        if k in kept_floats:
            m = kept_floats[k]
            assert np.array_equal(frame.values[:m], sent[frame.frame_index][:m])
        else:
            assert np.array_equal(frame.values, sent[frame.frame_index])
        assert frame.with_displacement is False and frame.with_reference is False
    got = {f.frame_index for f in out}
    assert len(got) == len(out)  # nothing returned twice
    for i in range(n):
        intact = i not in damaged
        # with or without a skeleton, a frame is confirmed by the next one: one followed by
        # garbage or by a damaged frame cannot be told from a frame with a damaged size
        if i + 1 < n and pieces[i + 1] != blobs[i + 1]:
            intact = False
        if intact:
            assert 100 + i in got, (i, stats)
    return out, stats


@settings(deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(n=st.integers(1, 10), seed=st.integers(0, 2**16), ops=damage,
       splits=st.lists(st.integers(1, 4000), max_size=12), strict=st.booleans())
def test_damage_never_invents_frames_and_spares_intact_ones(n, seed, ops, splits, strict):
    _check_damage(n, seed, ops, splits, strict)


# Found by the property test above: a frame cut to 99 bytes, then cut after its header and given
# one stray byte more than the 35 it had left, is its header and 36 zero bytes again: the exact
# bytes of a frame sent with nine zeros.
CUT_THEN_LONG_TAIL = dict(n=1, seed=0, ops=[("cut", 0, b"\x00", 62499),
                                            ("cut_long_tail", 0, b"\x00", 0)],
                          splits=[], strict=False)


def test_a_token_inside_a_value_confirms_no_frame_without_a_header_version():
    # Found by the property test: 8 stray bytes after a frame's header shift its values, and
    # the two that spill past its end begin with the token's bytes (a value's); with no
    # version of a header after that token, the frame is not taken as whole
    case = dict(n=1, seed=28120, ops=[("insert", 0, b"\x00", 0), ("insert", 0, b"\x00", 0)],
                splits=[], strict=False)
    sent = _frames(1, 28120)[0]
    blob = _encode([sent])[0]
    assert blob[92:94] == TOKEN  # the last two values' bytes begin with the token
    out, stats = _check_damage(**case)
    assert out == [] and stats.corrupt >= 1
    # the same token followed by a header's version still confirms the frame before it
    stream = blob + encode_binary(sent, frame_index=101, with_displacement=False,
                                  avatar_name="Seat")
    (first, second), _ = decode_all(stream)
    assert _same(first, sent, 100) and _same(second, sent, 101)


def test_a_cut_made_up_by_a_long_tail_is_a_whole_frame_no_reader_can_question():
    sent = _frames(1, 0)[0]
    stream = _encode([sent])[0][:64] + bytes(36)
    assert stream == encode_binary(np.zeros(9, dtype=np.float32), frame_index=100,
                                   with_displacement=False, avatar_name="Seat")
    for counts in (None, COUNTS):
        (frame,), stats = decode_all(stream, counts=counts)  # a valid frame decodes as sent
        assert frame.frame_index == 100 and not frame.values.any() and stats.corrupt == 0
    (frame,), _ = _check_damage(**CUT_THEN_LONG_TAIL)  # its values are not asked to hold
    assert not frame.values.any() and sent[:8].all()


def test_a_cut_made_up_by_inserted_bytes_keeps_only_the_values_before_them():
    # cut to 96 bytes, then 4 stray bytes after the header: 100 bytes again, values shifted
    (frame,), _ = _check_damage(n=1, seed=0, ops=[("cut", 0, b"\x00", 52396),
                                                  ("insert", 0, b"\x00", 0)],
                                splits=[], strict=True)
    np.testing.assert_array_equal(frame.values, np.r_[np.float32(0), _frames(1, 0)[0][:8]])


def test_a_flipped_count_made_up_by_inserted_bytes_is_a_whole_frame_without_a_skeleton():
    # Found by the property test: DataCount 9 -> 11 by a flipped bit, then twice 4 stray bytes
    # after the header: a frame of 11 values, as consistent as any; with the skeleton's count
    # (strict) the reader knows there are 9 and rejects it
    sent = _frames(1, 0)[0]
    frame = bytearray(_encode([sent])[0])
    frame[6] ^= 2
    frame[64:64] = bytes(8)
    (got,), _ = decode_all(bytes(frame))
    assert got.frame_index == 100
    np.testing.assert_array_equal(got.values, np.r_[np.zeros(2, np.float32), sent])
    out, stats = decode_all(bytes(frame), counts=COUNTS)
    assert out == [] and stats.corrupt >= 1
    _check_damage(n=1, seed=0, ops=[("header_flip", 0, b"\x00", 596),
                                    ("insert", 0, b"\x00", 0), ("insert", 0, b"\x00", 0)],
                  splits=[], strict=False)


def test_a_fragment_of_a_header_inside_a_frame_means_it_was_cut_short():
    # Found by the property test with 5000 examples (seed 2): 93 bytes of the other sender's
    # frame, then its first 7 bytes again, are 100 bytes followed by a token, twice. The second
    # fragment's token and version inside the first frame show it was cut short.
    other = encode_binary(OTHER, frame_index=7, with_displacement=False)
    ours = _encode(_frames(1, 0))[0]
    fragment_frame = other[:93] + other[:7]
    stream = 2 * fragment_frame + ours
    for counts in (None, COUNTS):
        for chunks in ([stream], [stream[:150], stream[150:]], [bytes([b]) for b in stream]):
            out, stats = decode_all(chunks, counts=counts)
            assert [f.frame_index for f in out] == [100] and stats.corrupt >= 2
    # the same bytes with the fragment's token and version gone come out: no reader can tell
    whole = other[:93] + b"\0" * 7
    assert [f.frame_index for f in decode_all(whole + ours)[0]] == [7, 100]


@settings(deadline=None)
@given(n=st.integers(1, 8), seed=st.integers(0, 2**16),
       flips=st.lists(st.integers(0, 10**6), min_size=1, max_size=6))
def test_flips_inside_values_are_all_that_can_slip_through(n, seed, flips):
    """The format has no checksum: a bit flipped inside a value or the frame index is
    undetectable, but it never breaks framing, so every frame still comes out once."""
    values = _frames(n, seed)
    stream = bytearray(b"".join(_encode(values)))
    size = 64 + 4 * 9
    for f in flips:
        k = f % n
        pos = [46, 47, 48, 49][f % 4] if f % 3 == 0 else 64 + (f // 7) % 36
        stream[k * size + pos] ^= 1 << (f % 8)
    out, stats = decode_all(bytes(stream), counts=COUNTS)
    assert len(out) + stats.corrupt == n  # a flip making a value NaN/inf rejects that frame
    for frame in out:
        assert frame.values.shape == (9,)


@settings(deadline=None)
@given(data=st.binary(max_size=3000), splits=st.lists(st.integers(0, 3000), max_size=8),
       strict=st.booleans(), datagram=st.booleans())
def test_random_bytes_raise_nothing(data, splits, strict, datagram):
    cuts = sorted({s % (len(data) + 1) for s in splits})
    chunks = [data[a:b] for a, b in zip([0] + cuts, cuts + [len(data)])]
    dec = StreamDecoder(counts=COUNTS if strict else None, datagram=datagram)
    for c in chunks:
        dec.feed(c)
    dec.flush()


@settings(deadline=None)
@given(n=st.integers(1, 8), seed=st.integers(0, 2**16),
       junk=st.lists(st.tuples(st.integers(0, 10**6), st.binary(max_size=40)), max_size=4),
       splits=st.lists(st.integers(1, 4000), max_size=10))
def test_string_frames_survive_junk(n, seed, junk, splits):
    values = _frames(n, seed)
    pieces = _encode(values, "string")
    for where, data in junk:
        k = where % n
        pieces[k] = data.replace(b"||", b"") + b"\r\n" + pieces[k]
    stream = b"".join(pieces)
    cuts = sorted({s % (len(stream) + 1) for s in splits})
    chunks = [stream[a:b] for a, b in zip([0] + cuts, cuts + [len(stream)])]
    out, stats = decode_all(chunks, counts=COUNTS)
    assert len(out) == n
    for frame, v in zip(out, values):
        np.testing.assert_array_equal(frame.values, v)
