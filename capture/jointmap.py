"""Which joint of a skeleton plays which anatomical role, for skeletons no profile knows.

Roles are those of `capture.profiles` (hips, left_upper_leg, ..., head). A joint map names the
joint of each role; it comes from a profile, from a joint-map file, or from `guess_joint_map`,
which reads the common naming schemes and the skeleton's structure:

* by name: a namespace is dropped ("mixamorig:LeftUpLeg"), a side is read from a prefix or a
  suffix in any spelling (Left, L, l_, _l, .L, R, right_ ...) and the rest matched against the
  words exporters use for each part (UpLeg / thigh / femur / hip, Leg / knee / shin / tibia /
  calf, Foot / ankle, Arm / upperarm / humerus, ForeArm / elbow / lowerarm, Hand / wrist,
  Shoulder / clavicle / collar, Hips / pelvis, Neck, Head / skull ...);
* by structure, for what the names leave open: the hips are the root, the legs' and arms'
  remaining joints follow down their chains in order, the head is the top of the spine chain
  and the neck its parent. A side is left (+X) or right (-X) in the rest pose (a body faces +Z).

Joint-map files are TOML, one `role = "joint"` line per role (optionally under `[roles]`);
a joint's first End Site is named `end:JOINT`.
"""

from __future__ import annotations

import difflib
import os
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .profiles import strip_namespace
from .skeleton import Skeleton, rest_fk

SIDED = ("shoulder", "upper_arm", "forearm", "hand", "fingers", "upper_leg", "lower_leg",
         "foot", "toe")
CENTRAL = ("hips", "spine", "chest", "neck", "head", "head_top")
ROLES = CENTRAL + tuple(f"{side}_{part}" for side in ("left", "right") for part in SIDED)
REQUIRED = ("hips", "neck", "head") + tuple(
    f"{side}_{part}" for side in ("left", "right")
    for part in ("upper_leg", "lower_leg", "foot", "upper_arm", "forearm", "hand"))

# a part's words, once the side and separators are gone (lower case)
PART_WORDS = {
    "hips": ("hips", "hip", "pelvis", "root", "hipsroot"),
    "spine": ("spine", "abdomen", "lowerback", "spine0", "torso", "waist"),
    "chest": ("chest", "thorax", "upperchest", "ribcage"),
    "neck": ("neck", "neck0", "necklower"),
    "head": ("head", "skull"),
    "upper_leg": ("upleg", "upperleg", "thigh", "femur", "hip", "uleg", "thighbone"),
    "lower_leg": ("leg", "lowerleg", "knee", "shin", "calf", "tibia", "crus", "loleg", "lleg"),
    "foot": ("foot", "ankle", "talus", "heel"),
    "toe": ("toe", "toes", "toebase", "ball", "toe0", "toesbase"),
    "shoulder": ("shoulder", "clavicle", "collar", "clav", "scapula"),
    "upper_arm": ("arm", "upperarm", "humerus", "uparm", "uarm"),
    "forearm": ("forearm", "lowerarm", "elbow", "radius", "ulna", "loarm", "larm"),
    "hand": ("hand", "wrist"),
    "fingers": ("fingerbase", "hand_middle1", "middle1", "handmiddle1", "index1",
                "handindex1"),
}
_SIDES = {"left": "left", "l": "left", "right": "right", "r": "right"}
_SEPARATORS = re.compile(r"[\s_.\-]+")


class JointMapError(ValueError):
    """A joint map (file or mapping) that does not fit the skeleton or names unknown roles."""


@dataclass(frozen=True)
class JointMapGuess:
    """What `guess_joint_map` found: `roles` role -> joint, `how` role -> "name" or
    "structure", the required roles it could not map and the joints it gave no role."""

    roles: dict[str, str]
    how: dict[str, str]
    missing: tuple[str, ...]
    unused: tuple[str, ...] = field(default=())

    def as_dict(self) -> dict:
        return {"roles": self.roles, "how": self.how, "missing": list(self.missing),
                "unused": list(self.unused)}


def _part_of(word: str, parts: tuple[str, ...]) -> str | None:
    for part in parts:
        if word in PART_WORDS.get(part, ()):
            return part
    return None


def name_role(name: str) -> str | None:
    """The role a joint name says, or None ("mixamorig:LeftForeArm" -> "left_forearm")."""
    plain = strip_namespace(name)
    candidates = []
    # a side as a prefix or suffix: Left, L, l_, _l, .L, camel-case LThigh, lhip ...
    for side_text, side in _SIDES.items():
        n = len(side_text)
        if plain[:n].lower() == side_text:
            rest = plain[n:]
            camel = rest[:1].isupper() or rest[:1] in "_.- "
            candidates.append((side, rest, 0 if camel or n > 1 else 1))
        if plain[-n:].lower() == side_text and len(plain) > n:
            rest = plain[:-n]
            candidates.append((side, rest, 0 if rest[-1:] in "_.- " or n > 1 else 1))
    candidates.sort(key=lambda c: c[2])
    for side, rest, _ in candidates:
        part = _part_of(_SEPARATORS.sub("", rest).lower(), SIDED)
        if part is not None:
            return f"{side}_{part}"
    return _part_of(_SEPARATORS.sub("", plain).lower(), CENTRAL)


def _children(skeleton: Skeleton) -> dict[int, list[int]]:
    kids: dict[int, list[int]] = {j: [] for j in range(skeleton.num_joints)}
    for j, p in enumerate(skeleton.parents):
        if p >= 0:
            kids[int(p)].append(j)
    return kids


def _by_name(skeleton: Skeleton) -> dict[str, str]:
    roles: dict[str, str] = {}
    for name in skeleton.names:  # parents first: the first joint of a role takes it
        role = name_role(name)
        if role is not None and role not in roles:
            roles[role] = name
    # a sided "hip" is the thigh, and a "shoulder" with no upper arm named is the upper arm
    # (SMPL's left_shoulder, whose clavicle is left_collar)
    for side in ("left", "right"):
        if f"{side}_upper_arm" not in roles and f"{side}_shoulder" in roles:
            shoulder = skeleton.index(roles[f"{side}_shoulder"])
            forearm = roles.get(f"{side}_forearm")
            if forearm is not None and skeleton.parents[skeleton.index(forearm)] == shoulder:
                roles[f"{side}_upper_arm"] = roles.pop(f"{side}_shoulder")
    return roles


def _chain_down(skeleton: Skeleton, kids, start: int, rest: np.ndarray) -> list[int]:
    """From `start`, the joints down its longest branch, skipping zero-length links."""
    chain, j = [], start
    while kids[j]:
        j = max(kids[j], key=lambda c: _depth(kids, c))
        if np.linalg.norm(rest[j] - rest[skeleton.parents[j]]) > 1e-6:
            chain.append(j)
    return chain


def _depth(kids, j: int) -> int:
    depth, level = 0, [j]
    while level:
        level = [c for k in level for c in kids[k]]
        depth += 1
    return depth


def _fill_limb(skeleton, kids, rest, roles, how, side: str, parts: tuple[str, ...]) -> None:
    """Completes a limb's roles down its chain from the first one named."""
    named = [p for p in parts if f"{side}_{p}" in roles]
    if not named:
        return
    first = parts.index(named[0])
    chain = [skeleton.index(roles[f"{side}_{named[0]}"])]
    chain += _chain_down(skeleton, kids, chain[0], rest)
    for offset, part in enumerate(parts[first:]):
        role = f"{side}_{part}"
        if role not in roles and offset < len(chain):
            roles[role] = skeleton.names[chain[offset]]
            how[role] = "structure"
        elif role in roles and offset < len(chain) and roles[role] != skeleton.names[chain[offset]]:
            break  # the names disagree with the chain: stop guessing along it


def guess_joint_map(skeleton: Skeleton) -> JointMapGuess:
    """Roles of a skeleton's joints from their names and the hierarchy (module docstring)."""
    roles = _by_name(skeleton)
    how = {r: "name" for r in roles}
    kids = _children(skeleton)
    rest = rest_fk(skeleton).positions if skeleton.unit_m else \
        rest_fk(skeleton.with_unit(1.0)).positions
    if "hips" not in roles:
        roles["hips"], how["hips"] = skeleton.names[0], "structure"
    for side in ("left", "right"):
        _fill_limb(skeleton, kids, rest, roles, how, side,
                   ("upper_leg", "lower_leg", "foot", "toe"))
        _fill_limb(skeleton, kids, rest, roles, how, side,
                   ("shoulder", "upper_arm", "forearm", "hand"))
    if "head" not in roles:  # the top of the chain up from the hips
        up = _chain_up(skeleton, kids, rest, skeleton.index(roles["hips"]))
        if up:
            roles["head"], how["head"] = skeleton.names[up[-1]], "structure"
    if "neck" not in roles and "head" in roles:
        parent = skeleton.parents[skeleton.index(roles["head"])]
        if parent >= 0 and skeleton.names[parent] not in roles.values():
            roles["neck"], how["neck"] = skeleton.names[parent], "structure"
    if "head" in roles and "head_top" not in roles:
        head = skeleton.index(roles["head"])
        if np.any(skeleton.end_site_parents == head):
            roles["head_top"], how["head_top"] = f"end:{roles['head']}", "structure"
    used = {v.removeprefix("end:") for v in roles.values()}
    return JointMapGuess(roles, how, tuple(r for r in REQUIRED if r not in roles),
                         tuple(n for n in skeleton.names if n not in used))


def _chain_up(skeleton: Skeleton, kids, rest: np.ndarray, start: int) -> list[int]:
    """From `start`, the joints of the branch that rises highest (the spine to the head)."""
    chain, j = [], start
    while kids[j]:
        j = max(kids[j], key=lambda c: _highest(kids, rest, c))
        chain.append(j)
    return chain


def _highest(kids, rest: np.ndarray, j: int) -> float:
    top, level = rest[j, 1], [j]
    while level:
        level = [c for k in level for c in kids[k]]
        if level:
            top = max(top, float(rest[level, 1].max()))
    return top


def check_joint_map(skeleton: Skeleton, mapping: dict, where: str = "joint map"
                    ) -> dict[str, str]:
    """A joint map checked against the roles and the skeleton (did-you-mean for typos)."""
    out = {}
    for role, joint in mapping.items():
        if role not in ROLES:
            near = difflib.get_close_matches(str(role), ROLES, n=1)
            hint = f" (did you mean {near[0]}?)" if near else ""
            raise JointMapError(f"{where}: unknown role {role!r}{hint}; roles are "
                                f"{list(ROLES)}")
        if not isinstance(joint, str) or joint.removeprefix("end:") not in skeleton.names:
            near = difflib.get_close_matches(str(joint), skeleton.names, n=1)
            hint = f" (did you mean {near[0]!r}?)" if near else ""
            raise JointMapError(f"{where}: {role} names {joint!r}, which is no joint of the "
                                f"skeleton{hint}")
        out[role] = joint
    return out


def read_joint_map(path: str | os.PathLike) -> dict[str, str]:
    """role -> joint from a joint-map file (TOML: `role = "joint"`, optionally under
    `[roles]`); not yet checked against a skeleton (`check_joint_map` does that)."""
    path = Path(path)
    if not path.exists():
        raise JointMapError(f"No joint-map file {path}")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise JointMapError(f"{path}: not a TOML joint map: {exc}") from None
    table = data.get("roles", data)
    bad = [k for k, v in table.items() if not isinstance(v, str)]
    if bad:
        raise JointMapError(f"{path}: expected role = \"joint name\" lines, got {bad[0]} = "
                            f"{table[bad[0]]!r}")
    return dict(table)
