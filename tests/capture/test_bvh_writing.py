"""Writing BVH: what `format_bvh` writes, `parse_bvh` reads back the same, or the writer refuses
it with a ValueError saying what was expected (never a file the reader refuses or reads as
something else, never a RecursionError)."""

import numpy as np
import pytest

from capture import Motion, Skeleton, format_bvh, parse_bvh, write_bvh
from capture.bvh import MAX_DEPTH

SIX = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
THREE = ("Zrotation", "Xrotation", "Yrotation")


def _skeleton(names=("Hips", "Spine"), offsets=((0, 0, 0), (0, 10, 0)), end=(0, 5, 0)):
    return Skeleton(names=names, parents=[-1, 0], offsets=offsets, channels=(SIX, THREE),
                    end_sites=[end], end_site_parents=[1])


def test_a_chain_as_deep_as_the_reader_takes_is_written_and_read_back(tmp_path):
    n = MAX_DEPTH  # the reader's limit; Python's recursion limit is about as deep
    chain = Skeleton(names=[f"j{k}" for k in range(n)], parents=np.arange(n) - 1,
                     offsets=np.tile([0.0, 1.0, 0.0], (n, 1)), channels=[THREE] * n,
                     end_sites=[[0.0, 1.0, 0.0]], end_site_parents=[n - 1], unit_m=0.01)
    turns = np.zeros((2, 3 * n))
    turns[1, 0] = 90.0  # the root turned about Z: the chain lies along -X
    path = tmp_path / "deep.bvh"
    write_bvh(path, chain, Motion(turns, 0.01))
    back = parse_bvh(path.read_bytes(), unit="cm")
    assert back.skeleton.names == chain.names
    np.testing.assert_array_equal(back.skeleton.parents, chain.parents)
    np.testing.assert_array_equal(back.skeleton.end_site_parents, [n - 1])
    tip = back.world_positions()[:, -1]  # the root 1 cm up, each joint 1 cm from its parent
    np.testing.assert_allclose(tip, [[0.0, n * 0.01, 0.0], [-(n - 1) * 0.01, 0.01, 0.0]],
                               atol=1e-9)


def test_two_roots_with_end_sites_between_children_keep_their_layout():
    sk = Skeleton(names=("a", "a1", "a2", "b"), parents=[-1, 0, 0, -1],
                  offsets=np.arange(12.0).reshape(4, 3), channels=(SIX, THREE, (), ("Yrotation",)),
                  end_sites=[[1, 2, 3], [4, 5, 6], [7, 8, 9]], end_site_parents=[0, 1, 3])
    ch = np.arange(2 * sk.num_channels, dtype=float).reshape(2, -1)
    back = parse_bvh(format_bvh(sk, Motion(ch, 0.02)), unit=None)
    assert back.skeleton.names == sk.names and back.skeleton.channels == sk.channels
    np.testing.assert_array_equal(back.skeleton.parents, sk.parents)
    # a's own End Site is written after its children, so it comes after a1's when read
    np.testing.assert_array_equal(back.skeleton.end_site_parents, [1, 0, 3])
    np.testing.assert_array_equal(back.skeleton.end_sites, [[4, 5, 6], [1, 2, 3], [7, 8, 9]])
    np.testing.assert_array_equal(back.motion.channels, ch)


@pytest.mark.parametrize("name", ["Left  Arm", "Arm ", " Arm", "\tArm", "Arm\nX", "Arm{1}",
                                  "Arm}", "", "x" * 257, "Arm\x00"])
def test_a_joint_name_the_reader_would_change_or_refuse_is_refused(name):
    with pytest.raises(ValueError, match="Expected joint names a BVH file keeps"):
        format_bvh(_skeleton(names=("Hips", name)), Motion(np.zeros((1, 9)), 0.04))


@pytest.mark.parametrize("name", ["Bip01 L Thigh", "mixamorig:Hips", "L.Arm", "Rücken",
                                  "A\u00a0B", "x" * 256])
def test_names_the_reader_keeps_are_written(name):
    back = parse_bvh(format_bvh(_skeleton(names=("Hips", name)), Motion(np.zeros((1, 9)), 0.04)),
                     unit=None)
    assert back.skeleton.names == ("Hips", name)


@pytest.mark.parametrize("kwargs, match", [
    (dict(offsets=((0, 0, 0), (0, np.nan, 0))), r"finite numbers .* in an OFFSET of joint 'Spine'"),
    (dict(offsets=((np.inf, 0, 0), (0, 1, 0))), r"finite numbers .* in an OFFSET of joint 'Hips'"),
    (dict(end=(0, -np.inf, 0)), r"finite numbers .* in an End Site OFFSET of joint 'Spine'"),
    (dict(offsets=((0, 0, 0), (0, 1e300, 0))), r"within \+-1e\+09 in an OFFSET of joint 'Spine'"),
])
def test_non_finite_offsets_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        format_bvh(_skeleton(**kwargs), Motion(np.zeros((1, 9)), 0.04))


@pytest.mark.parametrize("frame_time", [0.0, -0.01, float("nan"), float("inf"), 1e-7, 3601.0])
def test_a_frame_time_the_reader_refuses_is_refused(frame_time):
    with pytest.raises(ValueError, match=r"Expected a frame time from 1e-06 to 3600 s"):
        format_bvh(_skeleton(), Motion(np.zeros((1, 9)), frame_time))


@pytest.mark.parametrize("frame_time", [1e-6, 1 / 120, np.float32(1 / 30), 3600.0])
def test_frame_times_at_and_within_the_bounds_are_written(frame_time):
    back = parse_bvh(format_bvh(_skeleton(), Motion(np.zeros((1, 9)), frame_time)), unit=None)
    assert back.motion.frame_time == pytest.approx(float(frame_time), rel=1e-6)
