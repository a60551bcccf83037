"""The body's rig: joint frames, forward kinematics, the roles its joints play, and its BVH form.

Rig frames are world-aligned in the rest pose, so a posed joint j is given by its world rotation
Q_j and position p_j, and moves a rest point x to Q_j (x - P_j) + p_j, where P_j is its rest
position (`Body.joints`). Local rotations are relative to the parent's frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from capture import PROFILES, Skeleton, WorldPose, forward_kinematics
from capture.skeleton import depth_first_order

from solver.body.model import Body


# Rig joint -> the role it takes its retargeting target from: the rig profile's roles (one
# home, `capture.profiles`), less those placed otherwise. The clavicles have none: skeletons
# disagree on where a clavicle starts (CMU's start at the neck), so they keep their rest pose
# on the chest; the spine and chest joints are placed along the captured spine (RIG_CHAINS)
# and the head's tail aims at the top of the head (RIG_TAILS).
_PLACED_OTHERWISE = ("left_shoulder", "right_shoulder", "spine", "chest", "head_top")
RIG_ROLES = {joint: role for role, joint in PROFILES["sitrelax_rig"].roles.items()
             if role not in _PLACED_OTHERWISE}
# Rig joints placed along a captured chain: (chain start role, chain end role, joints).
RIG_CHAINS = (("hips", "neck", ("LowerBack", "Spine", "Spine1")), ("neck", "head", ("Neck1",)))
# A leaf joint aims its bone's tail at this role.
RIG_TAILS = {"Head": "head_top"}
# Joints oriented by the best fit (Kabsch) to several targets, which fixes their twist, and then
# turned to point exactly along the first, the chain that carries the posture. The chest aims
# at the shoulder joints, not at the clavicles' roots, which some skeletons put at the neck.
FIT_AIMS = {"Hips": ("LowerBack", "LeftUpLeg", "RightUpLeg"),
            "Spine1": ("Neck", "LeftArm", "RightArm")}
RIG_ROLES_INV = {v: k for k, v in RIG_ROLES.items()}


@dataclass(frozen=True, eq=False)
class RigMotion:
    """A body's rig posed over frames: local rotations and root positions, and world frames.

    local_rotmats : (T, J, 3, 3); root_positions : (T, 3) metres; world : WorldPose (T, J).
    """

    body: Body
    local_rotmats: np.ndarray
    root_positions: np.ndarray
    world: WorldPose

    def frame(self, t: int) -> WorldPose:
        return WorldPose(self.world.positions[t], self.world.rotmats[t])



def rest_offsets(body: Body) -> np.ndarray:
    """(J, 3) each joint's rest position relative to its parent (the root's is absolute)."""
    offsets = body.joints.copy()
    child = body.parents >= 0
    offsets[child] -= body.joints[body.parents[child]]
    return offsets


def rig_pose(body: Body, local_rotmats: np.ndarray, root_position: np.ndarray) -> WorldPose:
    """World joint frames from local rotations and the root's position.

    The other joints sit at their rest offsets from their parents (`Body.joints`).

    Parameters
    ----------
    body : Body
        The body whose rig is posed (J joints, joint 0 the root).
    local_rotmats : (..., J, 3, 3) float
        Rotation of each joint relative to its parent's frame (the root's: to the world).
    root_position : (..., 3) float
        World position of the root joint, metres.

    Returns
    -------
    WorldPose
        World positions (..., J, 3) in metres and rotations (..., J, 3, 3).
    """
    local_rotmats = np.asarray(local_rotmats, dtype=np.float64)
    trans = np.broadcast_to(rest_offsets(body), local_rotmats.shape[:-2] + (3,)).copy()
    trans[..., 0, :] = root_position
    return forward_kinematics(body.parents, local_rotmats, trans, body.levels)


def rest_pose(body: Body) -> WorldPose:
    """The rig's rest frames: identity rotations at the rest joint positions.

    Parameters
    ----------
    body : Body
        The body whose rig is meant (J joints).

    Returns
    -------
    WorldPose
        Positions (J, 3) in metres (a copy of `Body.joints`) and identity rotations (J, 3, 3).
    """
    n = len(body.joint_names)
    return WorldPose(body.joints.copy(), np.broadcast_to(np.eye(3), (n, 3, 3)).copy())


def swing(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(..., 3, 3) the smallest rotation turning direction a onto direction b (the identity
    where b is shorter than a tenth of a millimetre: no direction to follow)."""
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    length = np.linalg.norm(b, axis=-1, keepdims=True)
    b = np.where(length > 1e-4, b / np.maximum(length, 1e-300), a)
    axis = np.cross(a, b)
    sin = np.linalg.norm(axis, axis=-1, keepdims=True)
    cos = np.sum(a * b, axis=-1, keepdims=True)
    angle = np.arctan2(sin, cos)
    # opposite directions: any axis perpendicular to a
    perp = np.cross(a, np.where(np.abs(a[..., :1]) < 0.9, [1.0, 0, 0], [0, 1.0, 0]))
    axis = np.where(sin > 1e-9, axis / np.maximum(sin, 1e-300),
                    perp / np.linalg.norm(perp, axis=-1, keepdims=True))
    rotvec = (axis * angle).reshape(-1, 3)
    return Rotation.from_rotvec(rotvec).as_matrix().reshape(a.shape + (3,))


def kabsch(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation R minimising sum |R src_k - dst_k|^2; src, dst (..., K, 3)."""
    h = np.swapaxes(src, -1, -2) @ dst  # (..., 3, 3) = sum_k src_k dst_k^T
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(np.swapaxes(vt, -1, -2) @ np.swapaxes(u, -1, -2)))
    fix = np.ones(d.shape + (3,))
    fix[..., 2] = d
    return np.swapaxes(vt, -1, -2) @ (fix[..., :, None] * np.swapaxes(u, -1, -2))


def descendants(parents: np.ndarray) -> np.ndarray:
    """(J, J) D[j, m] = 1 when joint j is m or below it."""
    n = len(parents)
    d = np.eye(n)
    for j in range(n):
        p = parents[j]
        while p >= 0:
            d[j, p] = 1.0
            p = parents[p]
    return d


def rig_skeleton(body: Body):
    """The body's rig as a BVH skeleton in depth-first order (centimetres; the root with
    position channels, every joint with ZXY rotations), and the rig joint of each BVH joint."""
    order = np.array(depth_first_order(body.parents))
    new_index = np.empty(len(order), dtype=np.int64)
    new_index[order] = np.arange(len(order))
    parents = np.array([new_index[body.parents[j]] if body.parents[j] >= 0 else -1
                        for j in order])
    rot = ("Zrotation", "Xrotation", "Yrotation")
    channels = tuple((("Xposition", "Yposition", "Zposition") + rot) if p < 0 else rot
                     for p in parents)
    has_children = set(parents.tolist())
    leaves = [k for k in range(len(order)) if k not in has_children]
    ends = np.array([(body.tails[order[k]] - body.joints[order[k]]) * 100
                     for k in leaves]).reshape(-1, 3)
    names = tuple(body.joint_names[j] for j in order)
    return Skeleton(names, parents, rest_offsets(body)[order] * 100, channels, ends,
                    np.array(leaves, dtype=np.int64), unit_m=0.01), order


def pose_channels(body: Body, local: np.ndarray, root: np.ndarray) -> np.ndarray:
    """(C,) BVH channels of one rig pose for `rig_skeleton(body)`."""
    sk, order = rig_skeleton(body)
    quats = Rotation.from_matrix(local[order]).as_quat()
    trans = rest_offsets(body)[order].copy()
    trans[0] = root
    return sk.channels_from_pose(quats, trans)


def t_pose(body: Body, root_rotation: np.ndarray | None = None,
           root_position: np.ndarray | None = None):
    """The body's rig with its upper arms straight out sideways (a T-pose), optionally turned
    by a root rotation (3, 3) and moved; returns the world frames (J)."""
    n = len(body.joint_names)
    local = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    for side, sign in (("Left", 1.0), ("Right", -1.0)):
        arm, elbow = body.joint_index(f"{side}Arm"), body.joint_index(f"{side}ForeArm")
        local[arm] = swing(body.joints[elbow] - body.joints[arm], np.array([sign, 0.0, 0.0]))
    if root_rotation is not None:
        local[0] = root_rotation
    root = body.joints[0] if root_position is None else root_position
    return rig_pose(body, local, root)
