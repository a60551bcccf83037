"""BVH dialects met in the wild, writing, round trips, units and profiles."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from capture import (
    PROFILES,
    Bvh,
    Motion,
    Skeleton,
    UnitUnknownError,
    format_bvh,
    identify_profile,
    parse_bvh,
    read_bvh,
    write_bvh,
)
from capture.profiles import AXIS_NEURON_JOINTS, AXIS_STUDIO_JOINTS, CMU_JOINTS

from tests.conftest import recording

SMALL = """HIERARCHY
ROOT Hips
{
\tOFFSET 0.0 0.0 0.0
\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
\tJOINT Spine
\t{
\t\tOFFSET 0.0 10.0 0.0
\t\tCHANNELS 3 Zrotation Xrotation Yrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0.0 10.0 0.0
\t\t}
\t}
}
MOTION
Frames: 2
Frame Time: 0.0333333
0.0 90.0 0.0 0.0 0.0 0.0 0.0 0.0 0.0
0.0 90.0 0.0 10.0 0.0 0.0 5.0 0.0 0.0
"""


def test_small_file_by_hand():
    bvh = parse_bvh(SMALL, unit="cm")
    sk = bvh.skeleton
    assert sk.names == ("Hips", "Spine")
    assert sk.parents.tolist() == [-1, 0]
    assert sk.channels[0][3:] == ("Zrotation", "Xrotation", "Yrotation")
    np.testing.assert_array_equal(sk.end_sites, [[0.0, 10.0, 0.0]])
    pos = bvh.world_positions()
    # frame 1: hips at 0.9 m turned 10 degrees about Z; the spine's 10 cm offset tilts with it
    np.testing.assert_allclose(pos[1, 0], [0.0, 0.9, 0.0])
    a = np.radians(10.0)
    np.testing.assert_allclose(pos[1, 1], [-0.1 * np.sin(a), 0.9 + 0.1 * np.cos(a), 0.0],
                               atol=1e-12)
    assert bvh.motion.frame_time == pytest.approx(0.0333333)


def _variant(text, *, crlf=False, tabs_to_spaces=False, end_site="End Site"):
    if tabs_to_spaces:
        text = text.replace("\t", "    ")
    text = text.replace("End Site", end_site)
    if crlf:
        text = text.replace("\n", "\r\n")
    return text


@pytest.mark.parametrize("end_site", ["End Site", "END SITE", "end site", "EndSite", "End  site"])
@pytest.mark.parametrize("crlf", [False, True])
@pytest.mark.parametrize("spaces", [False, True])
def test_dialects_read_the_same(end_site, crlf, spaces):
    base = parse_bvh(SMALL, unit="cm")
    other = parse_bvh(_variant(SMALL, crlf=crlf, tabs_to_spaces=spaces, end_site=end_site),
                      unit="cm")
    np.testing.assert_array_equal(other.motion.channels, base.motion.channels)
    np.testing.assert_array_equal(other.skeleton.end_sites, base.skeleton.end_sites)
    np.testing.assert_allclose(other.world_positions(), base.world_positions())


def test_a_utf8_byte_order_mark_is_read_past():
    """Windows editors start a saved file with EF BB BF; the file reads as without it (and
    an error still counts lines from the first)."""
    base = parse_bvh(SMALL, unit="cm")
    marked = parse_bvh(b"\xef\xbb\xbf" + SMALL.encode("utf-8"), unit="cm")
    np.testing.assert_array_equal(marked.motion.channels, base.motion.channels)
    assert marked.skeleton.names == base.skeleton.names
    with pytest.raises(ValueError, match=":1: expected .HIERARCHY.*got .HIERARCH.$"):
        parse_bvh(b"\xef\xbb\xbfHIERARCH\n", unit="cm")


def test_braces_on_the_keyword_line_and_odd_names():
    text = (SMALL.replace("ROOT Hips\n{", "ROOT mixamorig:Hips {")
            .replace("JOINT Spine\n\t{", "JOINT Bip01 L.Spine{")
            .replace("\t\t}\n\t}\n}", "\t\t}\n\t}}"))
    bvh = parse_bvh(text, unit="cm")
    assert bvh.skeleton.names == ("mixamorig:Hips", "Bip01 L.Spine")
    np.testing.assert_allclose(bvh.world_positions(), parse_bvh(SMALL, unit="cm").world_positions())
    again = parse_bvh(format_bvh(bvh.skeleton, bvh.motion), unit="cm")
    assert again.skeleton.names == bvh.skeleton.names


@pytest.mark.parametrize("name", ["cmu_75_18_high_sit.bvh", "axis_neuron_standing_yxz.bvh",
                                  "cmu_82_05_floor_sit_excerpt.bvh"])
def test_read_write_read_round_trip(name, tmp_path):
    original = read_bvh(recording(name))
    out = tmp_path / "copy.bvh"
    write_bvh(out, original.skeleton, original.motion)
    copy = read_bvh(out)
    assert copy.skeleton.names == original.skeleton.names
    assert copy.skeleton.channels == original.skeleton.channels
    np.testing.assert_array_equal(copy.skeleton.parents, original.skeleton.parents)
    np.testing.assert_allclose(copy.skeleton.offsets, original.skeleton.offsets, atol=1e-6)
    np.testing.assert_allclose(copy.skeleton.end_sites, original.skeleton.end_sites, atol=1e-6)
    assert np.abs(copy.motion.channels - original.motion.channels).max() <= 1e-4
    assert copy.motion.frame_time == pytest.approx(original.motion.frame_time, rel=1e-6)
    assert copy.profile == original.profile


def _to_six_channels_zxy(bvh):
    """The same motion written as Axis Neuron's other layout: 6 channels per joint, ZXY."""
    sk = bvh.skeleton
    rot = sk.local_rotations(bvh.motion.channels)
    trans = sk.local_translations(bvh.motion.channels)
    six = Skeleton(sk.names, sk.parents, sk.offsets,
                   tuple(("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation",
                          "Yrotation") for _ in sk.names),
                   sk.end_sites, sk.end_site_parents, sk.unit_m)
    return six, Motion(six.channels_from_pose(rot, trans), bvh.motion.frame_time)


def _six_channels_written_and_read(original, tmp_path):
    """The recording as Axis writes it with displacement, written and read back."""
    six, motion = _to_six_channels_zxy(original)
    assert six.num_channels == 354
    path = tmp_path / "axis_6ch_zxy.bvh"
    write_bvh(path, six, motion)
    again = read_bvh(path)
    assert again.skeleton.num_channels == 354
    assert again.profile == "axis_neuron"
    return path, again


@pytest.mark.slow
def test_six_channels_on_every_joint_in_zxy(axis_standing, tmp_path):
    import bvhio

    original = read_bvh(axis_standing)
    path, again = _six_channels_written_and_read(original, tmp_path)
    np.testing.assert_allclose(again.world_positions(), original.world_positions(), atol=1e-5)
    # bvhio agrees on the layout with position channels on every joint
    root = bvhio.readAsHierarchy(str(path))
    root.loadPose(1000)
    theirs = np.array([tuple(j.PositionWorld) for j, _, _ in root.layout()]) * 0.01
    np.testing.assert_allclose(again.world_positions()[1000], theirs, atol=1e-4)


def test_six_channels_on_every_joint_in_zxy_on_a_sample_of_frames(axis_standing, tmp_path):
    """The default run's version of the test above: three frames of the recording (bvhio
    takes seconds to read all 2156)."""
    import bvhio

    whole = read_bvh(axis_standing)
    frames = [0, 1000, 2155]
    original = Bvh(whole.skeleton, Motion(whole.motion.channels[frames], whole.motion.frame_time),
                   whole.profile)
    path, again = _six_channels_written_and_read(original, tmp_path)
    np.testing.assert_allclose(again.world_positions(), whole.world_positions()[frames],
                               atol=1e-5)
    root = bvhio.readAsHierarchy(str(path))
    root.loadPose(1)
    theirs = np.array([tuple(j.PositionWorld) for j, _, _ in root.layout()]) * 0.01
    np.testing.assert_allclose(again.world_positions()[1], theirs, atol=1e-4)


@pytest.mark.parametrize("order", ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"])
def test_every_rotation_order_round_trips(order):
    rng = np.random.default_rng(7)
    channels = tuple(f"{axis}rotation" for axis in order)
    sk = Skeleton(("a", "b"), [-1, 0], [[0, 0, 0], [0, 1, 0]], (channels, channels), unit_m=1.0)
    rot = Rotation.random(50, random_state=rng)
    quats = np.stack([rot.as_quat(), rot[::-1].as_quat()], axis=1)  # (50, 2, 4)
    raw = sk.channels_from_pose(quats, np.broadcast_to(sk.offsets, (50, 2, 3)))
    back = sk.local_rotations(raw)
    dots = np.abs(np.sum(back * quats, axis=-1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-9)
    # and the channel order is the intrinsic sequence, composed left to right
    angles = raw[:, :3]
    expected = np.eye(3)
    for k, axis in enumerate(order):
        expected = expected @ Rotation.from_euler(axis.lower(), angles[0, k], degrees=True).as_matrix()
    np.testing.assert_allclose(sk.local_rotmats(raw)[0, 0], expected, atol=1e-12)


def test_partial_rotation_channels():
    sk = Skeleton(("a",), [-1], [[0, 0, 0]], (("Yrotation",),), unit_m=1.0)
    q = sk.local_rotations(np.array([[90.0]]))
    np.testing.assert_allclose(Rotation.from_quat(q[0, 0]).apply([1, 0, 0]), [0, 0, -1],
                               atol=1e-12)


def test_units_are_explicit():
    unknown = SMALL.replace("Hips", "Pelvis")
    bvh = parse_bvh(unknown)  # auto, and no profile matches
    assert bvh.profile is None and bvh.skeleton.unit_m is None
    with pytest.raises(UnitUnknownError, match="unit"):
        bvh.world_positions()
    metres = parse_bvh(unknown, unit="cm").world_positions()
    inches = parse_bvh(unknown, unit="in").world_positions()
    np.testing.assert_allclose(inches, metres * 2.54)
    np.testing.assert_allclose(parse_bvh(unknown, unit=0.01).world_positions(), metres)
    with pytest.raises(ValueError, match="got 'furlong'"):
        parse_bvh(unknown, unit="furlong")
    with pytest.raises(ValueError, match="positive"):
        parse_bvh(unknown, unit=-1.0)


def test_recognised_profiles_bring_their_units(cmu_high_sit, axis_standing):
    assert read_bvh(cmu_high_sit).skeleton.unit_m == pytest.approx(0.056444)
    assert read_bvh(axis_standing).skeleton.unit_m == pytest.approx(0.01)
    # an explicit unit wins over the profile's
    assert read_bvh(cmu_high_sit, unit="in").skeleton.unit_m == pytest.approx(0.0254)


def test_profiles():
    assert identify_profile(AXIS_NEURON_JOINTS) == "axis_neuron"
    assert identify_profile(AXIS_STUDIO_JOINTS) == "axis_studio"
    assert identify_profile(CMU_JOINTS) == "cmu"
    assert identify_profile([f"Take 001:{n}" for n in AXIS_STUDIO_JOINTS]) == "axis_studio"
    assert identify_profile(CMU_JOINTS[:-1]) is None
    assert identify_profile(["Hips", "Spine"]) is None
    assert len(AXIS_NEURON_JOINTS) == len(AXIS_STUDIO_JOINTS) == 59
    assert len(CMU_JOINTS) == 31
    studio = set(AXIS_STUDIO_JOINTS)
    assert "Spine3" not in studio and {"Neck", "Neck1"} <= studio
    for profile in PROFILES.values():
        joints = {r.removeprefix("end:") for r in profile.roles.values()}
        assert joints <= set(profile.joints)


def test_axis_studio_hierarchy_round_trips(axis_standing, tmp_path):
    """Axis Studio's hierarchy: Spine2 carries Neck -> Neck1 -> Head and both shoulders."""
    legacy = read_bvh(axis_standing)
    sk = legacy.skeleton
    names = ["Neck" if n == "Spine3" else "Neck1" if n == "Neck" else n for n in sk.names]
    parents = sk.parents.copy()
    for shoulder in ("RightShoulder", "LeftShoulder"):
        parents[sk.index(shoulder)] = sk.index("Spine2")
    studio = Skeleton(tuple(names), parents, sk.offsets, sk.channels, sk.end_sites,
                      sk.end_site_parents, sk.unit_m)
    path = tmp_path / "studio.bvh"
    write_bvh(path, studio, legacy.motion)
    again = read_bvh(path)
    assert again.profile == "axis_studio"
    assert again.skeleton.unit_m == 0.01
    assert again.skeleton.names == tuple(names)
    np.testing.assert_array_equal(again.skeleton.parents, parents)
    # the shoulders now hang from Spine2, so they no longer follow the upper spine bone
    moved = again.world_positions()[:, again.skeleton.index("RightShoulder")]
    before = legacy.world_positions()[:, sk.index("RightShoulder")]
    assert np.abs(moved - before).max() > 0.01


def test_writing_needs_depth_first_order():
    sk = Skeleton(("root", "a", "b", "a_child"), [-1, 0, 0, 1], np.zeros((4, 3)),
                  ((), (), (), ()), unit_m=1.0)
    with pytest.raises(ValueError, match="depth-first"):
        format_bvh(sk)


def test_header_only_and_write_is_atomic(tmp_path):
    bvh = parse_bvh(SMALL, unit="cm")
    header = format_bvh(bvh.skeleton)
    empty = parse_bvh(header, unit="cm")
    assert empty.motion.num_frames == 0 and empty.skeleton.names == bvh.skeleton.names
    target = tmp_path / "keep.bvh"
    target.write_text(SMALL)
    bad = Motion(np.full((1, 9), np.nan), 0.01)
    with pytest.raises(ValueError, match="finite"):
        write_bvh(target, bvh.skeleton, bad)
    assert target.read_text() == SMALL
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.bvh"]
