"""Linear blend skinning: posing a body's skin by its rig's joint frames.

A posed joint j moves a rest point x to Q_j (x - P_j) + p_j (see `solver.body.rig`). Skinning
blends these per-joint affine maps with the sparse weight matrix W (V x J): M = W @ A, one
(3 x 4) map per vertex, applied to the rest vertices and (rotation part) normals.
"""

from __future__ import annotations

import numpy as np

from capture import WorldPose

from solver.body.model import Body


def skinning_maps(body: Body, pose: WorldPose, vertices: np.ndarray | None = None
                  ) -> np.ndarray:
    """(V, 3, 4) blended affine map of each vertex (or of the given vertex indices) for one
    pose."""
    rot = pose.rotmats
    trans = pose.positions - np.einsum("jab,jb->ja", rot, body.joints)
    per_joint = np.concatenate([rot, trans[:, :, None]], axis=2).reshape(len(rot), 12)
    weights = body.weights if vertices is None else body.weights[vertices]
    return np.asarray(weights @ per_joint).reshape(-1, 3, 4)


def lowest_height(body: Body, pose: WorldPose) -> float:
    """The lowest posed skin height (y, metres), skinning only the vertices that can be lowest.

    A vertex's posed point is the weighted mean of where each of its joints carries it, and a
    joint j carries a vertex at rest distance L from it no lower than p_j,y - L: so
    sum_j w_j (p_j,y - L_j) bounds it from below, and only the vertices whose bound lies under
    the lowest-bounded vertex's posed height need skinning. The result is the full skin's
    minimum exactly (the same arithmetic per vertex)."""
    rows, cols, w, lever = body.weight_levers
    bound = np.bincount(rows, w * (pose.positions[cols, 1] - lever),
                        minlength=len(body.vertices))
    probe = int(np.argmin(bound))
    ceiling = _skinned(body, pose, np.array([probe]))[0, 1]
    candidates = np.flatnonzero(bound <= ceiling + 1e-9)
    return float(_skinned(body, pose, candidates)[:, 1].min())


def _skinned(body: Body, pose: WorldPose, vertices: np.ndarray) -> np.ndarray:
    maps = skinning_maps(body, pose, vertices)
    return np.einsum("vab,vb->va", maps[:, :, :3], body.vertices[vertices]) + maps[:, :, 3]


def skin(body: Body, pose: WorldPose, normals: bool = True
         ) -> tuple[np.ndarray, np.ndarray | None]:
    """Posed vertices (V, 3) and unit normals (V, 3) of a body for one rig pose.

    Parameters
    ----------
    body : Body
        The body to pose (V skin vertices, J rig joints).
    pose : WorldPose
        One pose of the rig: positions (J, 3) in metres and rotations (J, 3, 3), without a
        frame axis (`RigMotion.frame(t)`).
    normals : bool, default True
        Whether to pose the rest normals too.

    Returns
    -------
    vertices : (V, 3) float
        Posed skin vertices, metres.
    normals : (V, 3) float or None
        Unit normals, the rest normals turned by each vertex's blended linear map and
        renormalised; None when `normals` is False.

    Raises
    ------
    TypeError
        If `pose` is not a `WorldPose`.
    ValueError
        If the pose's rotations are not of shape (J, 3, 3).
    """
    if not (hasattr(pose, "rotmats") and hasattr(pose, "positions")):
        raise TypeError(f"Expected a WorldPose (one frame of a RigMotion: `motion.frame(t)`), "
                        f"got {type(pose).__name__}")
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
