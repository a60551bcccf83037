"""Posing a body: rig forward kinematics and linear blend skinning.

Rig frames are world-aligned in the rest pose, so a posed joint j is given by its world rotation
Q_j and position p_j, and moves a rest point x to Q_j (x - P_j) + p_j, where P_j is its rest
position. Skinning blends these per-joint affine maps with the sparse weight matrix W (V x J):
M = W @ A, one (3 x 4) map per vertex, applied to the rest vertices and (rotation part) normals.
"""

from __future__ import annotations

import numpy as np

from capture import WorldPose, forward_kinematics

from .body import Body


def rest_offsets(body: Body) -> np.ndarray:
    """(J, 3) each joint's rest position relative to its parent (the root's is absolute)."""
    offsets = body.joints.copy()
    child = body.parents >= 0
    offsets[child] -= body.joints[body.parents[child]]
    return offsets


def rig_pose(body: Body, local_rotmats: np.ndarray, root_position: np.ndarray) -> WorldPose:
    """World joint frames from local rotations and the root's position.

    local_rotmats : (..., J, 3, 3) rotation of each joint relative to its parent's frame.
    root_position : (..., 3) metres.
    """
    local_rotmats = np.asarray(local_rotmats, dtype=np.float64)
    trans = np.broadcast_to(rest_offsets(body), local_rotmats.shape[:-2] + (3,)).copy()
    trans[..., 0, :] = root_position
    return forward_kinematics(body.parents, local_rotmats, trans)


def rest_pose(body: Body) -> WorldPose:
    """The rig's rest frames: identity rotations at the rest joint positions."""
    n = len(body.joint_names)
    return WorldPose(body.joints.copy(), np.broadcast_to(np.eye(3), (n, 3, 3)).copy())


def skinning_maps(body: Body, pose: WorldPose) -> np.ndarray:
    """(V, 3, 4) blended affine map of each vertex for one pose."""
    rot = pose.rotmats
    trans = pose.positions - np.einsum("jab,jb->ja", rot, body.joints)
    per_joint = np.concatenate([rot, trans[:, :, None]], axis=2).reshape(len(rot), 12)
    return np.asarray(body.weights @ per_joint).reshape(-1, 3, 4)


def skin(body: Body, pose: WorldPose, normals: bool = True
         ) -> tuple[np.ndarray, np.ndarray | None]:
    """Posed vertices (V, 3) and unit normals (V, 3) of a body for one rig pose."""
    if pose.rotmats.shape != (len(body.joint_names), 3, 3):
        raise ValueError(f"Expected one pose of {len(body.joint_names)} joints, got rotations of "
                         f"shape {pose.rotmats.shape}")
    maps = skinning_maps(body, pose)
    lin = maps[:, :, :3]
    verts = np.einsum("vab,vb->va", lin, body.vertices) + maps[:, :, 3]
    if not normals:
        return verts, None
    n = np.einsum("vab,vb->va", lin, body.normals)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return verts, n
