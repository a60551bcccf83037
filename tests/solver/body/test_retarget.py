"""Retargeting captured skeletons onto the body rig, and posed bodies."""

import numpy as np
import pytest

from capture import Skeleton, read_bvh, skeleton_fk
from solver.body.model import BodyShape, make_body
from solver.body.poses import PoseSourceError, load_pose, pose_body
from solver.body.retarget import RetargetError, joint_map_for, place, retarget, role_positions
from solver.body.skinning import skin

from tests.conftest import recording

FILES = ["cmu_75_18_high_sit.bvh", "cmu_75_17_medium_sit.bvh", "cmu_82_05_floor_sit_excerpt.bvh",
         "axis_neuron_standing_yxz.bvh"]
# major bones: rig joints from -> to, and the captured roles from -> to
MAJOR = {
    "left thigh": ("LeftUpLeg", "LeftLeg", "left_upper_leg", "left_lower_leg"),
    "left shin": ("LeftLeg", "LeftFoot", "left_lower_leg", "left_foot"),
    "right thigh": ("RightUpLeg", "RightLeg", "right_upper_leg", "right_lower_leg"),
    "right shin": ("RightLeg", "RightFoot", "right_lower_leg", "right_foot"),
    "left upper arm": ("LeftArm", "LeftForeArm", "left_upper_arm", "left_forearm"),
    "left forearm": ("LeftForeArm", "LeftHand", "left_forearm", "left_hand"),
    "right upper arm": ("RightArm", "RightForeArm", "right_upper_arm", "right_forearm"),
    "right forearm": ("RightForeArm", "RightHand", "right_forearm", "right_hand"),
    "spine": ("Hips", "Neck", "hips", "neck"),
    "neck": ("Neck", "Head", "neck", "head"),
}


def _angles(a, b):
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1, 1)))


@pytest.mark.parametrize("name", FILES)
@pytest.mark.parametrize("shape", [BodyShape(), BodyShape(gender=1, weight=0.9, height=0.8)])
def test_major_bones_point_as_captured(name, shape):
    bvh = read_bvh(recording(name))
    body = make_body(shape)
    motion = retarget(bvh.skeleton, bvh.motion.channels, body)
    captured = role_positions(bvh.skeleton, skeleton_fk(bvh.skeleton, bvh.motion.channels),
                              joint_map_for(bvh.skeleton))
    rig = motion.world.positions
    for bone, (j0, j1, r0, r1) in MAJOR.items():
        ours = rig[:, body.joint_index(j1)] - rig[:, body.joint_index(j0)]
        theirs = captured[r1] - captured[r0]
        angles = _angles(ours, theirs)
        assert np.median(angles) < 3.0, (bone, np.median(angles))
        assert angles.max() < 10.0, (bone, angles.max())


def test_seated_frame_gives_a_seated_body():
    bvh = read_bvh(recording("cmu_75_18_high_sit.bvh"))
    body = make_body()
    motion = place(retarget(bvh.skeleton, bvh.motion.channels[39:40], body), lowest=0.0)
    joints = motion.world.positions[0]
    for side in ("Left", "Right"):
        thigh = joints[body.joint_index(f"{side}Leg")] - joints[body.joint_index(f"{side}UpLeg")]
        elevation = np.degrees(np.arcsin(abs(thigh[1]) / np.linalg.norm(thigh)))
        assert elevation < 20, (side, elevation)
    verts, _ = skin(body, motion.frame(0), normals=False)
    pelvis_above_feet = joints[0, 1] - verts[body.part_mask(["feet"]), 1].min()
    assert 0.4 < pelvis_above_feet < 0.6, pelvis_above_feet
    # and standing, the same body's pelvis is far higher
    standing = place(retarget(bvh.skeleton, bvh.motion.channels[3:4], body), lowest=0.0)
    assert standing.world.positions[0, 0, 1] - joints[0, 1] > 0.3


def test_root_translation_scales_with_leg_length():
    bvh = read_bvh(recording("cmu_75_18_high_sit.bvh"))
    short = retarget(bvh.skeleton, bvh.motion.channels[39:40], make_body(BodyShape(height=0.1)))
    tall = retarget(bvh.skeleton, bvh.motion.channels[39:40], make_body(BodyShape(height=0.9)))
    ratio = tall.root_positions[0, 1] / short.root_positions[0, 1]
    assert ratio > 1.2


def test_place_by_pelvis_and_lowest_point():
    bvh = read_bvh(recording("cmu_75_18_high_sit.bvh"))
    body = make_body()
    motion = retarget(bvh.skeleton, bvh.motion.channels[[10, 39]], body)
    by_pelvis = place(motion, pelvis=0.6)
    np.testing.assert_allclose(by_pelvis.world.positions[:, 0, 1], 0.6)
    by_floor = place(motion, lowest=0.05)
    for t in range(2):
        verts, _ = skin(body, by_floor.frame(t), normals=False)
        assert verts[:, 1].min() == pytest.approx(0.05, abs=1e-9)
    with pytest.raises(ValueError, match="exactly one"):
        place(motion)


def test_unknown_skeleton_needs_a_joint_map():
    bvh = read_bvh(recording("cmu_75_18_high_sit.bvh"))
    sk = bvh.skeleton
    renamed = Skeleton(tuple(f"jnt_{n}" for n in sk.names), sk.parents, sk.offsets, sk.channels,
                       sk.end_sites, sk.end_site_parents, sk.unit_m)
    body = make_body()
    with pytest.raises(RetargetError, match="give a joint map"):
        retarget(renamed, bvh.motion.channels[39:40], body)
    roles = {r: ("end:jnt_" + j[4:] if j.startswith("end:") else "jnt_" + j)
             for r, j in joint_map_for(sk).items()}
    mapped = retarget(renamed, bvh.motion.channels[39:40], body, joint_map=roles)
    plain = retarget(sk, bvh.motion.channels[39:40], body)
    np.testing.assert_allclose(mapped.world.positions, plain.world.positions, atol=1e-12)
    with pytest.raises(RetargetError, match="no such joint"):
        retarget(sk, bvh.motion.channels[:1], body, joint_map={"hips": "Pelvis"})


def test_pose_sources(tmp_path):
    from posedb import PoseLibrary

    lib = PoseLibrary(tmp_path / "p.h5", create=True)
    take = lib.import_bvh(recording("cmu_75_18_high_sit.bvh"))
    lib.add_pose(take.id, 39, "perch")
    body = make_body()
    from_db = pose_body(load_pose("db:perch", tmp_path / "p.h5"), body)
    from_file = pose_body(load_pose(f"bvh:{recording('cmu_75_18_high_sit.bvh')}#frame=39"), body)
    np.testing.assert_allclose(from_db.world.positions, from_file.world.positions, atol=1e-5)
    for spec, message in [("perch", "Expected a pose as"), ("db:perch", "needs a pose library"),
                          (f"{recording('cmu_75_18_high_sit.bvh')}#frame=77", "0..76"),
                          # one frame a reference (the file was read as '...bvh#frame=39')
                          ("bvh:bundled:cmu_75_18_high_sit.bvh#frame=39#frame=2",
                           "Expected a pose as"),
                          # a blank file name (was "No such file or directory:  ")
                          ("bvh: #frame=1", "Expected a pose as")]:
        with pytest.raises(PoseSourceError, match=message):
            load_pose(spec)
