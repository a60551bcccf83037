"""Joint-name profiles of the skeletons met in the wild.

Four are known: Perception Neuron as written by Axis Neuron (spine ends in Spine3, then Neck),
by Axis Studio (Spine2 carries Neck -> Neck1 -> Head and the shoulders; no Spine3), the CMU
BVH conversion (31 joints), and the rig of sitrelax's own bodies (the CMU names but for one
finger joint a hand, in centimetres), which relaxed poses are written in. A profile also states the file's length unit and which joint plays
each anatomical role, so later stages can retarget any of them onto a body rig.

Names are compared after dropping a namespace prefix ("Take1:Hips" -> "Hips").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Mapping

def _pn_arm(side: str) -> tuple[str, ...]:
    # Each finger but the thumb starts with an in-hand (metacarpal) bone, e.g. RightInHandIndex.
    fingers = tuple(f"{side}HandThumb{k}" for k in (1, 2, 3))
    for finger in ("Index", "Middle", "Ring", "Pinky"):
        fingers += (f"{side}InHand{finger}",) + tuple(f"{side}Hand{finger}{k}" for k in (1, 2, 3))
    return (f"{side}Shoulder", f"{side}Arm", f"{side}ForeArm", f"{side}Hand") + fingers


_PN_LEGS = ("Hips", "RightUpLeg", "RightLeg", "RightFoot", "LeftUpLeg", "LeftLeg", "LeftFoot")

#: Perception Neuron skeleton from Axis Neuron, in broadcast (depth-first) order.
AXIS_NEURON_JOINTS = (_PN_LEGS + ("Spine", "Spine1", "Spine2", "Spine3", "Neck", "Head")
                      + _pn_arm("Right") + _pn_arm("Left"))
#: Perception Neuron skeleton from Axis Studio, in broadcast (depth-first) order.
AXIS_STUDIO_JOINTS = (_PN_LEGS + ("Spine", "Spine1", "Spine2", "Neck", "Neck1", "Head")
                      + _pn_arm("Right") + _pn_arm("Left"))
#: CMU BVH conversion skeleton, in file order.
CMU_JOINTS = (
    "Hips", "LHipJoint", "LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToeBase",
    "RHipJoint", "RightUpLeg", "RightLeg", "RightFoot", "RightToeBase",
    "LowerBack", "Spine", "Spine1", "Neck", "Neck1", "Head",
    "LeftShoulder", "LeftArm", "LeftForeArm", "LeftHand", "LeftFingerBase", "LeftHandIndex1",
    "LThumb",
    "RightShoulder", "RightArm", "RightForeArm", "RightHand", "RightFingerBase",
    "RightHandIndex1", "RThumb",
)

#: The rig of sitrelax bodies (MakeHuman's CMU-MB rig), as relaxed poses are written.
RIG_JOINTS = tuple(n.replace("HandIndex1", "HandFinger1") for n in CMU_JOINTS)

# Both Perception Neuron and CMU name their limbs alike.
_LIMB_ROLES = {
    "hips": "Hips", "head": "Head", "head_top": "end:Head",
    "left_upper_leg": "LeftUpLeg", "left_lower_leg": "LeftLeg", "left_foot": "LeftFoot",
    "right_upper_leg": "RightUpLeg", "right_lower_leg": "RightLeg", "right_foot": "RightFoot",
    "left_shoulder": "LeftShoulder", "left_upper_arm": "LeftArm", "left_forearm": "LeftForeArm",
    "left_hand": "LeftHand", "right_shoulder": "RightShoulder", "right_upper_arm": "RightArm",
    "right_forearm": "RightForeArm", "right_hand": "RightHand",
}
_PN_ROLES = {
    **_LIMB_ROLES, "spine": "Spine", "chest": "Spine2",
    "left_toe": "end:LeftFoot", "right_toe": "end:RightFoot",
    "left_fingers": "LeftHandMiddle1", "right_fingers": "RightHandMiddle1",
}
_CMU_ROLES = {
    **_LIMB_ROLES, "spine": "LowerBack", "chest": "Spine1", "neck": "Neck",
    "left_toe": "LeftToeBase", "right_toe": "RightToeBase",
    "left_fingers": "LeftHandIndex1", "right_fingers": "RightHandIndex1",
}


@dataclass(frozen=True)
class Profile:
    """A known skeleton: its joints, its file length unit and its joints' anatomical roles.

    A role names a joint, or `end:JOINT` for the first End Site of that joint.
    """

    name: str
    description: str
    joints: tuple[str, ...]
    unit_m: float
    roles: Mapping[str, str]


PROFILES: dict[str, Profile] = {
    "axis_neuron": Profile(
        "axis_neuron", "Perception Neuron, Axis Neuron (Spine3)", AXIS_NEURON_JOINTS, 0.01,
        {**_PN_ROLES, "neck": "Neck"},
    ),
    "axis_studio": Profile(
        "axis_studio", "Perception Neuron, Axis Studio (Neck, Neck1)", AXIS_STUDIO_JOINTS, 0.01,
        {**_PN_ROLES, "neck": "Neck"},
    ),
    "cmu": Profile(
        "cmu", "CMU motion capture database (31 joints)", CMU_JOINTS, 0.056444, _CMU_ROLES,
    ),
    "sitrelax_rig": Profile(
        "sitrelax_rig", "sitrelax body rig (relaxed poses)", RIG_JOINTS, 0.01,
        {**_CMU_ROLES, "left_fingers": "LeftFingerBase", "right_fingers": "RightFingerBase"},
    ),
}


def strip_namespace(name: str) -> str:
    """Joint name without an exporter's namespace prefix ("Take1:Hips" -> "Hips")."""
    return name.rsplit(":", 1)[-1]


def identify_profile(names: Iterable[str]) -> str | None:
    """The name of the known profile whose joints all appear in `names`, or None.

    A skeleton may carry extra joints (end effectors, props); the profile still applies.
    """
    present = {strip_namespace(n) for n in names}
    for profile in PROFILES.values():
        if present.issuperset(profile.joints):
            # Axis Studio's joints are a subset of neither Neuron nor CMU, but a file holding
            # Spine3 is Axis Neuron even if it also carries Neck1.
            if profile.name == "axis_studio" and "Spine3" in present:
                continue
            return profile.name
    return None
