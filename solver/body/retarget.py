"""Retargeting captured skeletons onto a body's rig.

The captured posture is transferred by bone directions, so rest poses (T-pose or A-pose), bone
lengths and joint counts may all differ. For every rig joint a target point is taken from the
captured joints: the joint playing the same anatomical role (see `capture.profiles`), or, along
the spine and neck, the point at the same fraction of the captured chain's length. Then, parents
first, each rig joint turns so that its bones point at the targets of its children: by the
smallest rotation when it has one such child, and by the best-fitting rotation (Kabsch) when it
has several (the pelvis: both hips and the spine; the chest: the neck and both shoulders), which
also fixes its twist. Joints with no target keep their rest pose relative to their parent.

The root moves as the captured hips do, scaled by the ratio of leg lengths, so a seat height
scales with the body; `place` can then put the lowest skin point or the pelvis at a height.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from capture import PROFILES, Skeleton, WorldPose, identify_profile, skeleton_fk
from capture.jointmap import guess_joint_map
from capture.profiles import strip_namespace
from capture.skeleton import rest_fk

from solver.body.model import Body
from solver.body.rig import (FIT_AIMS, RIG_CHAINS, RIG_ROLES, RIG_ROLES_INV, RIG_TAILS, RigMotion,
                             kabsch, rig_pose, swing)
from solver.body.skinning import lowest_height

MIN_LEG = 0.05  # metres: captured legs shorter than this have no length to scale by
REQUIRED_ROLES = ("hips", "neck", "head", "left_upper_leg", "left_lower_leg", "left_foot",
                  "right_upper_leg", "right_lower_leg", "right_foot", "left_upper_arm",
                  "left_forearm", "left_hand", "right_upper_arm", "right_forearm", "right_hand")


class RetargetError(ValueError):
    """A skeleton that cannot be retargeted as given (unknown joints, missing roles)."""


def joint_map_for(skeleton: Skeleton, profile: str | None = None,
                  joint_map: Mapping[str, str] | None = None) -> dict[str, str]:
    """Role -> joint name for a captured skeleton: the profile's, then the skeleton's own map,
    then `joint_map`; roles still missing are guessed from the joint names and the hierarchy
    (`capture.jointmap.guess_joint_map`).

    Parameters
    ----------
    skeleton : Skeleton
        The captured skeleton whose joints play the roles.
    profile : str, optional
        Name of a known profile (a key of `capture.PROFILES`); by default the one
        `identify_profile` recognises from the joint names, if any. Profile joint names are
        matched without their namespace prefix.
    joint_map : mapping of str to str, optional
        Role -> joint name entries that override (or, with no recognised profile, replace) the
        profile's. A name ``"end:JOINT"`` stands for the end site of JOINT.

    Returns
    -------
    dict of str to str
        Role -> joint name of `skeleton` (``"end:"``-prefixed for an end site), covering at
        least every role in `REQUIRED_ROLES`.

    Raises
    ------
    RetargetError
        If a required role has no joint, or a joint named for a role is not in the skeleton.
    """
    roles: dict[str, str] = {}
    profile = profile or identify_profile(skeleton.names)
    if profile is not None:
        by_plain = {strip_namespace(n): n for n in skeleton.names}
        if profile not in PROFILES:
            raise RetargetError(f"Expected a profile from {sorted(PROFILES)}, got {profile!r}")
        for role, name in PROFILES[profile].roles.items():
            end = name.startswith("end:")
            plain = name.removeprefix("end:")
            if plain in by_plain:
                roles[role] = ("end:" if end else "") + by_plain[plain]
    roles.update(dict(skeleton.joint_map))  # stored with the skeleton (a library take)
    roles.update(joint_map or {})
    missing = [r for r in REQUIRED_ROLES if r not in roles]
    if missing:  # what neither a profile nor a map says, read from the names and structure
        guess = guess_joint_map(skeleton)
        taken = set(roles.values())
        for role, joint in guess.roles.items():
            if role not in roles and joint not in taken:
                roles[role] = joint
        missing = [r for r in REQUIRED_ROLES if r not in roles]
    if missing:
        raise RetargetError(
            f"Expected a joint for each of the roles {missing}: no profile, joint map, joint "
            "name or the skeleton's structure gives them; give a joint map (a TOML file of "
            'role = "joint" lines, --joint-map)'
        )
    for role, name in roles.items():
        if name.removeprefix("end:") not in skeleton.names:
            raise RetargetError(f"Joint map names {name!r} for role {role!r}, but the skeleton "
                                f"has no such joint")
    return roles


def role_positions(skeleton: Skeleton, pose: WorldPose, roles: Mapping[str, str]
                   ) -> dict[str, np.ndarray]:
    """(..., 3) world position of each role's joint (or end site) in metres."""
    out = {}
    unit = skeleton.require_unit()
    for role, name in roles.items():
        if name.startswith("end:"):
            j = skeleton.index(name[4:])
            sites = np.flatnonzero(skeleton.end_site_parents == j)
            if not sites.size:
                continue
            off = skeleton.end_sites[sites[0]] * unit
            out[role] = pose.positions[..., j, :] + pose.rotmats[..., j, :, :] @ off
        else:
            out[role] = pose.positions[..., skeleton.index(name), :]
    return out


def _chain(skeleton: Skeleton, start: str, end: str) -> list[int]:
    """Joint indices from `start` down to `end` (end's ancestors up to start)."""
    s, e = skeleton.index(start), skeleton.index(end)
    path = [e]
    while path[-1] != s:
        p = int(skeleton.parents[path[-1]])
        if p < 0:
            raise RetargetError(f"Joint {end!r} does not descend from {start!r}")
        path.append(p)
    return path[::-1]


def _along(points: np.ndarray, fractions: np.ndarray) -> np.ndarray:
    """Points at arc-length fractions along polylines. points (..., K, 3) -> (..., F, 3)."""
    seg = np.linalg.norm(np.diff(points, axis=-2), axis=-1)  # (..., K-1)
    cum = np.concatenate([np.zeros(seg.shape[:-1] + (1,)), np.cumsum(seg, axis=-1)], axis=-1)
    total = np.maximum(cum[..., -1:], 1e-12)
    rel = cum / total  # (..., K)
    out = np.empty(points.shape[:-2] + (len(fractions), 3))
    for i, f in enumerate(fractions):
        k = np.clip((rel < f).sum(axis=-1) - 1, 0, points.shape[-2] - 2)  # segment index
        r0 = np.take_along_axis(rel, k[..., None], -1)[..., 0]
        r1 = np.take_along_axis(rel, k[..., None] + 1, -1)[..., 0]
        t = np.clip((f - r0) / np.maximum(r1 - r0, 1e-12), 0, 1)[..., None]
        p0 = np.take_along_axis(points, k[..., None, None].repeat(3, -1), -2)[..., 0, :]
        p1 = np.take_along_axis(points, k[..., None, None].repeat(3, -1) + 1, -2)[..., 0, :]
        out[..., i, :] = p0 + t * (p1 - p0)
    return out


def _targets(body: Body, roles_pos: dict[str, np.ndarray], batch: tuple) -> dict[int, np.ndarray]:
    """Target point of each rig joint that has one, (..., 3)."""
    names = body.joint_names
    targets = {}
    for joint, role in RIG_ROLES.items():
        if joint in names and role in roles_pos:
            targets[names.index(joint)] = roles_pos[role]
    for start, end, joints in RIG_CHAINS:
        if start not in roles_pos or end not in roles_pos:
            continue
        rig_path = [RIG_ROLES_INV[start]] + list(joints) + [RIG_ROLES_INV[end]]
        pts = body.joints[[names.index(n) for n in rig_path]]
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        fractions = np.cumsum(seg)[:-1] / seg.sum()
        src = roles_pos.get(f"_chain:{start}:{end}")
        if src is None:
            src = np.stack([roles_pos[start], roles_pos[end]], axis=-2)
        placed = _along(src, fractions)
        for k, joint in enumerate(joints):
            targets[names.index(joint)] = placed[..., k, :]
    return targets


def solve_rig(body: Body, roles_pos: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """World rotations (..., J, 3, 3) of the rig that point its bones at the role targets, and
    the local rotations (..., J, 3, 3) they amount to."""
    batch = roles_pos["hips"].shape[:-1]
    targets = _targets(body, roles_pos, batch)
    names, parents, rest = body.joint_names, body.parents, body.joints
    n = len(names)
    children = {j: [c for c in range(n) if parents[c] == j] for j in range(n)}
    world = np.empty(batch + (n, 3, 3))
    local = np.empty(batch + (n, 3, 3))
    eye = np.broadcast_to(np.eye(3), batch + (3, 3))
    for j in range(n):
        p = int(parents[j])
        inherited = eye if p < 0 else world[..., p, :, :]
        base = targets.get(j)
        if base is None and p >= 0 and p in targets and np.linalg.norm(rest[j] - rest[p]) < 1e-6:
            base = targets[p]  # a zero-length bone sits where its parent does
            targets[j] = base
        fit = [names.index(a) for a in FIT_AIMS.get(names[j], ()) if a in names]
        if base is not None and fit and all(c in targets for c in fit):
            src = np.stack([(rest[c] - rest[j]) / np.linalg.norm(rest[c] - rest[j]) for c in fit])
            dst = np.stack([targets[c] - base for c in fit], axis=-2)
            dst = dst / np.maximum(np.linalg.norm(dst, axis=-1, keepdims=True), 1e-12)
            best = kabsch(np.broadcast_to(src, dst.shape), dst)
            c = fit[0]
            world[..., j, :, :] = swing(best @ (rest[c] - rest[j]), targets[c] - base) @ best
        else:
            aim = None  # the first child (or grandchild past a zero-length bone) with a target
            for c in children[j]:
                if np.linalg.norm(rest[c] - rest[j]) < 1e-6:
                    grand = [g for g in children[c] if g in targets]
                    if grand:
                        aim = grand[0]
                        break
                elif c in targets:
                    aim = c
                    break
            tail_role = RIG_TAILS.get(names[j])
            if base is not None and aim is not None:
                cur = inherited @ (rest[aim] - rest[j])
                world[..., j, :, :] = swing(cur, targets[aim] - base) @ inherited
            elif base is not None and tail_role in roles_pos:
                cur = inherited @ (body.tails[j] - rest[j])
                world[..., j, :, :] = swing(cur, roles_pos[tail_role] - base) @ inherited
            else:
                world[..., j, :, :] = inherited
        local[..., j, :, :] = world[..., j, :, :] if p < 0 else \
            np.swapaxes(world[..., p, :, :], -1, -2) @ world[..., j, :, :]
    return world, local


def leg_length(positions: Mapping[str, np.ndarray]) -> float:
    """Mean of the two legs' hip-knee plus knee-ankle lengths."""
    total = 0.0
    for side in ("left", "right"):
        hip, knee, ankle = (np.asarray(positions[f"{side}_{r}"])
                            for r in ("upper_leg", "lower_leg", "foot"))
        total += np.linalg.norm(knee - hip) + np.linalg.norm(ankle - knee)
    return total / 2


def retarget(skeleton: Skeleton, channels: np.ndarray, body: Body, *,
             profile: str | None = None, joint_map: Mapping[str, str] | None = None
             ) -> RigMotion:
    """The body's rig in the captured posture for every frame.

    Forward kinematics of the raw channels, then `retarget_pose`.

    Parameters
    ----------
    skeleton : Skeleton
        The captured skeleton; its length unit must be known (`Skeleton.unit_m`).
    channels : (T, C) float
        Raw channels of `skeleton`: positions in the skeleton's file unit, rotations in degrees.
        A single frame (C,) is taken as T = 1.
    body, profile, joint_map
        As for `retarget_pose`.

    Returns
    -------
    RigMotion
        As `retarget_pose` returns it, over the T frames.
    """
    channels = np.atleast_2d(np.asarray(channels, dtype=np.float64))
    return retarget_pose(skeleton, skeleton_fk(skeleton, channels), body, profile=profile,
                         joint_map=joint_map)


def retarget_pose(skeleton: Skeleton, pose: WorldPose, body: Body, *,
                  profile: str | None = None, joint_map: Mapping[str, str] | None = None
                  ) -> RigMotion:
    """As `retarget`, from the captured skeleton's world frames (T, J) in metres.

    A skeleton that is a sitrelax rig (a relaxed pose, written by `sitrelax relax`) hands its
    local rotations over unchanged: the rigs share their rest orientations, so the posture
    carries across bodies exactly, and only the root moves in proportion to the leg length.
    That shortcut is taken only without a `joint_map`. Otherwise the rig is solved by bone
    directions (see the module docstring) and its root is the captured hips' position scaled by
    the ratio of the rig's leg length to the skeleton's.

    Parameters
    ----------
    skeleton : Skeleton
        The captured skeleton; its length unit must be known (`Skeleton.unit_m`).
    pose : WorldPose
        The skeleton's world frames over T frames: positions (T, J, 3) in metres and rotations
        (T, J, 3, 3), J the skeleton's joints (the leading frame axis is required).
    body : Body
        The body whose rig is posed.
    profile : str, optional
        The skeleton's profile (see `joint_map_for`); recognised from its joint names by default.
    joint_map : mapping of str to str, optional
        Role -> joint name overrides (see `joint_map_for`).

    Returns
    -------
    RigMotion
        The rig over the T frames: local rotations (T, J, 3, 3), root positions (T, 3) in metres
        and world frames (T, J), J the body's rig joints.

    Raises
    ------
    RetargetError
        If the skeleton's joints cannot be given the roles the retargeting needs.
    """
    if joint_map is None and sorted(skeleton.names) == sorted(body.joint_names) and \
            (profile or identify_profile(skeleton.names)) == "sitrelax_rig":
        return _same_rig(skeleton, pose, body)
    _require_finite(skeleton.names, pose.positions, "the captured positions")
    _require_finite(skeleton.names, pose.rotmats, "the captured rotations")
    roles = joint_map_for(skeleton, profile, joint_map)
    pos = role_positions(skeleton, pose, roles)
    # the captured spine and neck as polylines, for placing the rig's joints along them
    for start, end, _ in RIG_CHAINS:
        if not (roles[start].startswith("end:") or roles[end].startswith("end:")):
            path = _chain(skeleton, roles[start], roles[end])
            pos[f"_chain:{start}:{end}"] = pose.positions[:, path, :]
    rig_rest = {role: body.joints[body.joint_index(j)] for j, role in RIG_ROLES.items()
                if j in body.joint_names}
    scale = leg_length(rig_rest) / captured_leg_length(skeleton, pose, roles)
    _, local = solve_rig(body, pos)
    root = pos["hips"] * scale
    motion = RigMotion(body, local, root, rig_pose(body, local, root))
    _require_finite(body.joint_names, motion.world.positions, "the posed rig")
    return motion


def captured_leg_length(skeleton: Skeleton, pose: WorldPose, roles: Mapping[str, str]
                        ) -> float:
    """The captured legs' length (m): from the skeleton's OFFSETs (its rest pose), or, where
    the offsets leave the legs without length (a file whose position channels carry the
    bones), from the first frame's joint positions. Never 0."""
    joints = {k: v for k, v in roles.items() if not v.startswith("end:")}
    length = leg_length(role_positions(skeleton, rest_fk(skeleton), joints))
    if length < MIN_LEG:
        length = leg_length({k: v[0] for k, v in role_positions(skeleton, pose, joints).items()})
    if not length >= MIN_LEG:
        legs = [roles[f"{side}_{r}"] for side in ("left", "right")
                for r in ("upper_leg", "lower_leg", "foot")]
        raise RetargetError(f"Expected legs of some length, got {length:.3g} m from the joints "
                            f"{legs} in the offsets and in the first frame")
    return length


def _require_finite(names, values: np.ndarray, what: str) -> None:
    """RetargetError naming the first frame and joint (axis -2 of (T, J, ...)) that holds a
    NaN or an infinity."""
    flat = values.reshape(values.shape[0], values.shape[1], -1)
    bad = ~np.isfinite(flat).all(axis=2)
    if bad.any():
        t, j = (int(i) for i in np.argwhere(bad)[0])
        raise RetargetError(f"Expected finite values in {what}, got a NaN or an infinity at "
                            f"joint {names[j]!r} in frame {t}")


def _same_rig(skeleton: Skeleton, pose: WorldPose, body: Body) -> RigMotion:
    index = [skeleton.names.index(n) for n in body.joint_names]
    rot = np.asarray(pose.rotmats)[:, index]  # (T, J, 3, 3) in the body's joint order
    parents = body.parents
    parent_rot = np.where(parents[None, :, None, None] >= 0, rot[:, np.maximum(parents, 0)],
                          np.eye(3))
    local = np.swapaxes(parent_rot, -1, -2) @ rot
    # the captured rig's leg against this body's: hip above the ankle at rest
    hip, foot = skeleton.names.index("LeftUpLeg"), skeleton.names.index("LeftFoot")
    rest = rest_fk(skeleton).positions
    own = body.joints[body.joint_index("LeftUpLeg")] - body.joints[body.joint_index("LeftFoot")]
    scale = np.linalg.norm(own) / np.linalg.norm(rest[hip] - rest[foot])
    root = np.asarray(pose.positions)[:, index[0]] * scale
    return RigMotion(body, local, root, rig_pose(body, local, root))


def place(motion: RigMotion, *, lowest: float | None = None, pelvis: float | None = None
          ) -> RigMotion:
    """Moves each frame vertically: its lowest skin point, or its pelvis, to the given height
    (the rig posed again at the moved root; the skin is not skinned here).

    Only the root's y changes; the local rotations are kept.

    Parameters
    ----------
    motion : RigMotion
        The posed rig over T frames.
    lowest : float, optional
        Height (y, metres) to put each frame's lowest posed skin point at.
    pelvis : float, optional
        Height (y, metres) to put each frame's root joint (the pelvis) at. Give exactly one of
        `lowest` and `pelvis`.

    Returns
    -------
    RigMotion
        The same body and local rotations (T, J, 3, 3), with root positions (T, 3) in metres
        moved along y and the world frames (T, J) posed again.

    Raises
    ------
    ValueError
        If neither or both of `lowest` and `pelvis` are given.
    """
    if (lowest is None) == (pelvis is None):
        raise ValueError("Expected exactly one of lowest= or pelvis=")
    root = motion.root_positions.copy()
    for t in range(len(root)):
        if pelvis is not None:
            root[t, 1] += pelvis - motion.world.positions[t, 0, 1]
        else:
            root[t, 1] += lowest - lowest_height(motion.body, motion.frame(t))
    return RigMotion(motion.body, motion.local_rotmats, root,
                     rig_pose(motion.body, motion.local_rotmats, root))
