"""The dialect corpus: every file reads, equal to bvhio where bvhio reads it.

fixtures/bvh/dialects/ is made by fixtures/make_dialect_bvh.py. Where bvhio refuses a file
(several roots, `END SITE`, braces on keyword lines, `Frames:3`, a decimal comma), the test says
so by asserting that bvhio raises, and checks the file against its twin (the same content in a
dialect bvhio reads) or against positions computed by hand.
"""

import json

import bvhio
import numpy as np
import pytest

from capture import read_bvh, skeleton_fk

from ..conftest import FIXTURES

CORPUS = FIXTURES / "bvh" / "dialects"
EXPECTED = json.loads((CORPUS / "expected.json").read_text())
ATOL_M = 1e-6  # bvhio computes in float32 (glm): about 1e-7 m on a 2 m skeleton


def _read(name):
    """The file read with its profile's unit, or centimetres for the synthetic skeletons."""
    bvh = read_bvh(CORPUS / name)
    return bvh if bvh.skeleton.unit_m is not None else read_bvh(CORPUS / name, unit="cm")


def _world(bvh):
    return skeleton_fk(bvh.skeleton, bvh.motion.channels).positions


def _bvhio_world(path, unit_m):
    root = bvhio.readAsHierarchy(str(path))
    layout = root.layout()
    out = np.empty((len(root.Keyframes), len(layout), 3))
    for f in range(len(out)):
        root.loadPose(f)
        out[f] = [tuple(joint.PositionWorld) for joint, _, _ in layout]
    return [joint.Name for joint, _, _ in layout], out * unit_m


def test_corpus_is_complete():
    files = sorted(p.name for p in CORPUS.glob("*.bvh"))
    assert files == sorted(EXPECTED)
    assert len(files) >= 10
    assert sum(not e["bvhio"] for e in EXPECTED.values()) >= 3


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_dialect_reads(name):
    bvh = _read(name)
    assert bvh.skeleton.num_joints == EXPECTED[name]["joints"]
    assert bvh.motion.channels.shape == (EXPECTED[name]["frames"], bvh.skeleton.num_channels)
    assert np.isfinite(_world(bvh)).all()


@pytest.mark.parametrize("name", sorted(n for n, e in EXPECTED.items() if e["bvhio"]))
def test_world_positions_equal_bvhio(name):
    bvh = _read(name)
    names, expected = _bvhio_world(CORPUS / name, bvh.skeleton.unit_m)
    assert names == list(bvh.skeleton.names)
    np.testing.assert_allclose(_world(bvh), expected, rtol=0, atol=ATOL_M)


@pytest.mark.parametrize("name", sorted(n for n, e in EXPECTED.items() if not e["bvhio"]))
def test_bvhio_refuses_and_the_file_reads_as_its_twin_or_by_hand(name):
    # bvhio refuses these dialects with a SyntaxError; if a newer bvhio reads one, move it to
    # the bvhio comparison.
    with pytest.raises(SyntaxError):
        bvhio.readAsHierarchy(str(CORPUS / name))
    twin = EXPECTED[name]["twin"]
    if twin is None:
        assert name in HAND_CHECKED
        return
    ours, theirs = _read(name), _read(twin)
    assert EXPECTED[twin]["bvhio"]
    assert ours.skeleton.names == theirs.skeleton.names
    assert ours.skeleton.channels == theirs.skeleton.channels
    np.testing.assert_array_equal(ours.skeleton.end_sites, theirs.skeleton.end_sites)
    assert ours.motion.frame_time == theirs.motion.frame_time
    np.testing.assert_array_equal(ours.motion.channels, theirs.motion.channels)
    np.testing.assert_allclose(_world(ours), _world(theirs), rtol=0, atol=1e-12)


def test_rotation_subset_by_hand():
    # bend (0,1,0) turns Z then X; twist (0,1,0) turns Y; tip (0,1,0) turns X.
    bvh = read_bvh(CORPUS / "synthetic_rotation_subset.bvh", unit="m")
    assert bvh.skeleton.channels[1:] == (("Zrotation", "Xrotation"), ("Yrotation",),
                                         ("Xrotation",))
    pos = _world(bvh)
    # frame 0: bend Z 90 sends twist's offset to -X; twist's Y 90 leaves +Y alone
    np.testing.assert_allclose(pos[0], [[0, 0, 0], [0, 1, 0], [-1, 1, 0], [-2, 1, 0]],
                               atol=1e-12)
    # frame 1: bend X 90 sends +Y to +Z
    np.testing.assert_allclose(pos[1], [[0, 0, 0], [0, 1, 0], [0, 1, 1], [0, 1, 2]],
                               atol=1e-12)


def test_two_roots_by_hand():
    bvh = read_bvh(CORPUS / "synthetic_two_roots.bvh", unit="cm")
    assert bvh.skeleton.names == ("a", "a_child", "b", "b_child")
    assert bvh.skeleton.parents.tolist() == [-1, 0, -1, 2]
    # a at (1, 2, 3) turned 90 degrees about Z: its child's (0, 10, 0) becomes (-10, 0, 0);
    # b at its position channels (100, 0, 0); b's child 5 along Z whatever b_child's own turn
    np.testing.assert_allclose(_world(bvh)[0] * 100,
                               [[1, 2, 3], [-9, 2, 3], [100, 0, 0], [100, 0, 5]], atol=1e-9)


HAND_CHECKED = {"synthetic_two_roots.bvh"}


def test_course_skeleton_has_its_names_and_end_sites():
    bvh = _read("synthetic_course_skeleton_end_names.bvh")
    sk = bvh.skeleton
    assert sk.names[:5] == ("pelvis", "l_hip", "l_knee", "l_ankle", "l_foot")
    assert bvh.profile is None and sk.num_joints == 24
    assert len(sk.end_sites) == 5  # two toes, two hands' fingers, the head top
