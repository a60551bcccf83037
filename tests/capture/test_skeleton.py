"""Forward kinematics on hand-computed chains, and skeleton validation."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from capture import Skeleton, SkeletonError, forward_kinematics, joint_levels


def test_two_bone_chain_by_hand():
    # root at (1, 0, 0) turned 90 degrees about Z; a 2 m bone along local X, then a 1 m bone
    # along local X whose joint is turned -90 degrees about Z.
    parents = np.array([-1, 0, 1])
    rot = Rotation.from_euler("z", [[90.0], [-90.0], [0.0]], degrees=True).as_matrix()
    trans = np.array([[1.0, 0, 0], [2.0, 0, 0], [1.0, 0, 0]])
    pose = forward_kinematics(parents, rot, trans)
    np.testing.assert_allclose(pose.positions, [[1, 0, 0], [1, 2, 0], [2, 2, 0]], atol=1e-12)
    np.testing.assert_allclose(pose.rotmats[2], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(pose.quaternions()[0], [0, 0, np.sqrt(0.5), np.sqrt(0.5)],
                               atol=1e-12)


def test_batched_and_unbatched_agree():
    rng = np.random.default_rng(3)
    parents = np.array([-1, 0, 1, 1, 0, 4])
    rot = Rotation.random(4 * 3 * 6, random_state=rng).as_matrix().reshape(4, 3, 6, 3, 3)
    trans = rng.normal(size=(4, 3, 6, 3))
    batched = forward_kinematics(parents, rot, trans)
    single = forward_kinematics(parents, rot[2, 1], trans[2, 1])
    np.testing.assert_allclose(batched.positions[2, 1], single.positions)
    np.testing.assert_allclose(batched.rotmats[2, 1], single.rotmats)
    # the definition, joint by joint
    for j, p in enumerate(parents):
        if p < 0:
            continue
        np.testing.assert_allclose(batched.rotmats[..., j, :, :],
                                   batched.rotmats[..., p, :, :] @ rot[..., j, :, :], atol=1e-12)
        step = np.einsum("...ij,...j->...i", batched.rotmats[..., p, :, :], trans[..., j, :])
        np.testing.assert_allclose(batched.positions[..., j, :],
                                   batched.positions[..., p, :] + step, atol=1e-12)


def test_levels():
    levels = joint_levels([-1, 0, 1, 1, 0, 4])
    assert [lv.tolist() for lv in levels] == [[0], [1, 4], [2, 3, 5]]
    with pytest.raises(SkeletonError, match="precede"):
        joint_levels([-1, 2, 0])


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(parents=[-1, 1]), "precede"),
        (dict(offsets=np.zeros((3, 3))), r"offsets` of shape \(2, 3\)"),
        (dict(names=("a", "a")), "unique"),
        (dict(channels=(("Xrotation",), ("Wrotation",))), "Wrotation"),
        (dict(channels=(("Xrotation", "Xrotation"), ())), "distinct"),
        (dict(unit_m=0.0), "positive unit_m"),
    ],
)
def test_bad_skeletons_are_named(kwargs, message):
    base = dict(names=("a", "b"), parents=[-1, 0], offsets=np.zeros((2, 3)),
                channels=(("Xrotation",), ()))
    base.update(kwargs)
    with pytest.raises(SkeletonError, match=message):
        Skeleton(**base)


def test_channels_of_wrong_width_are_rejected():
    sk = Skeleton(("a",), [-1], [[0, 0, 0]], (("Xposition", "Zrotation"),), unit_m=1.0)
    with pytest.raises(SkeletonError, match=r"\(\.\.\., 2\), got \(4, 3\)"):
        sk.local_rotations(np.zeros((4, 3)))


def test_skeleton_is_immutable():
    sk = Skeleton(("a",), [-1], [[0, 0, 0]], ((),), unit_m=1.0)
    with pytest.raises(ValueError):
        sk.offsets[0, 0] = 1.0
    with pytest.raises(AttributeError):
        sk.unit_m = 2.0
