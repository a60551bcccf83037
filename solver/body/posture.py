"""What a pose is, read from its rig's joint positions: seated upright, reclined, sitting on the
floor, lying, perching, or standing.

The joints are the CMU-MB rig's (`Body.joint_names`) in metres, Y up, the pose placed with its
lowest skin point on the floor (y = 0), as `solver.body.retarget.place(motion, lowest=0.0)` and
`solver.scene.placement.place_person` leave it. The figures (`PostureFigures`):

    pelvis_height    the pelvis (root joint) over the floor, metres
    pelvis_over_feet the pelvis over the mean of the ankles, metres
    trunk_angle_deg  the trunk (hips' middle to neck) from vertical, degrees, positive when it
                     leans back (behind the hips, against the pelvis's forward direction)
    thigh_angle_deg  the thighs (hip to knee) below horizontal, degrees (90 standing, about 0
                     seated on a chair, negative with the knees above the hips)

The classes and their rules, tried in this order (`classify_posture`):

    lying      |trunk| >= 60 degrees with the pelvis under 0.35 m
    standing   thighs >= 60 degrees below horizontal with the pelvis >= 0.6 m over the feet
    reclined   trunk leaning back >= 25 degrees (a reclined body placed on the floor has its
               pelvis low too: the lean decides)
    floor      pelvis under 0.28 m (sitting on the floor)
    perched    thighs 20-60 degrees below horizontal (half standing, on a high seat)
    seated     the rest (upright on a seat, thighs about level)

The thresholds come from the bundled recordings (README, "Designing from poses"): seated
frames have the pelvis 0.35-0.47 m high, thighs -25..-4 degrees, trunk within 8 degrees of
vertical; the floor sitter's pelvis is 0.17 m high, trunk back 14 degrees; a standing pose's
thighs are 86-90 degrees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

POSTURES = ("seated", "reclined", "floor", "lying", "perched", "standing")

LYING_TRUNK_DEG = 60.0
LYING_PELVIS_M = 0.35
STANDING_THIGH_DEG = 60.0
STANDING_PELVIS_OVER_FEET_M = 0.6
FLOOR_PELVIS_M = 0.28
RECLINED_TRUNK_DEG = 25.0
PERCHED_THIGH_DEG = 20.0


class PostureError(ValueError):
    """Joint positions a posture cannot be read from."""


@dataclass(frozen=True)
class PostureFigures:
    """The figures a posture is classified by (see the module docstring); lengths in metres,
    angles in degrees."""

    pelvis_height: float
    pelvis_over_feet: float
    trunk_angle_deg: float
    thigh_angle_deg: float


_JOINTS = ("Hips", "LeftUpLeg", "RightUpLeg", "LeftLeg", "RightLeg", "LeftFoot", "RightFoot",
           "Neck")


def pelvis_forward(left_hip: np.ndarray, right_hip: np.ndarray) -> np.ndarray:
    """(3,) the way the pelvis faces, level (its y zero, not normalised): the hips' axis turned
    about up; zero where the hips stand vertical (a body lying on its side)."""
    forward = np.cross(np.asarray(left_hip) - np.asarray(right_hip), [0.0, 1.0, 0.0])
    forward[1] = 0.0
    return forward


def posture_figures(positions: np.ndarray, joint_names) -> PostureFigures:
    """The posture figures of one posed rig.

    Parameters
    ----------
    positions : (J, 3) float, metres, Y up, the floor at y = 0.
    joint_names : the J joint names (the rig's: Hips, LeftUpLeg, LeftLeg, LeftFoot, Neck, ...).

    Returns
    -------
    PostureFigures. Raises PostureError for a missing joint or positions that are not finite.
    """
    p = np.asarray(positions, dtype=np.float64)
    names = list(joint_names)
    if p.ndim != 2 or p.shape != (len(names), 3):
        raise PostureError(f"Expected positions of shape ({len(names)}, 3), got {p.shape}")
    if not np.isfinite(p).all():
        raise PostureError("Expected finite joint positions, got NaN or infinity")
    missing = [j for j in _JOINTS if j not in names]
    if missing:
        raise PostureError(f"Expected the joints {list(_JOINTS)}, missing {missing}")
    hips, lhip, rhip, lknee, rknee, lfoot, rfoot, neck = (p[names.index(j)] for j in _JOINTS)
    hip_mid = (lhip + rhip) / 2
    trunk = neck - hip_mid
    forward = pelvis_forward(lhip, rhip)
    tilt = np.degrees(np.arccos(np.clip(trunk[1] / max(np.linalg.norm(trunk), 1e-9), -1, 1)))
    sideways = np.linalg.norm(forward) < 1e-6  # the hips stand vertical: lying on a side
    back = trunk @ forward <= 0 if not sideways else True
    thighs = np.stack([lknee - lhip, rknee - rhip])
    below = np.degrees(np.arcsin(np.clip(-thighs[:, 1] / np.linalg.norm(thighs, axis=1),
                                         -1, 1)))
    return PostureFigures(float(hips[1]), float(hips[1] - (lfoot[1] + rfoot[1]) / 2),
                          float(tilt if back else -tilt), float(below.mean()))


def classify_posture(figures: PostureFigures) -> str:
    """The posture (one of `POSTURES`) of its figures, by the rules of the module docstring."""
    f = figures
    if abs(f.trunk_angle_deg) >= LYING_TRUNK_DEG and f.pelvis_height < LYING_PELVIS_M:
        return "lying"
    if f.thigh_angle_deg >= STANDING_THIGH_DEG and \
            f.pelvis_over_feet >= STANDING_PELVIS_OVER_FEET_M:
        return "standing"
    if f.trunk_angle_deg >= RECLINED_TRUNK_DEG:
        return "reclined"
    if f.pelvis_height < FLOOR_PELVIS_M:
        return "floor"
    if PERCHED_THIGH_DEG <= f.thigh_angle_deg < STANDING_THIGH_DEG:
        return "perched"
    return "seated"
