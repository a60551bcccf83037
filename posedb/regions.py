"""The body regions a surface supports, the coarser names older files use, and the regions each
use of a surface supports by default: the one vocabulary of scenarios, pose libraries, the
command line, the studio and the pressure mat's figures.

A region is a piece of the body as seating studies report it, made of the rig bones that move
it (`solver.body.model` derives each skin vertex's region from the skinning weights):

    head        the head and neck
    upper_back  the chest and shoulder blades, with the shoulders (the collar bones)
    lower_back  the waist and the small of the back
    pelvis      the hips with the buttocks, which carry most of a seated body's weight
    thighs      the upper legs, hip to knee
    calves      the lower legs, knee to ankle
    feet        the feet and toes
    upper_arms  shoulder to elbow
    forearms    elbow to wrist
    hands       the hands and fingers

The coarse parts of earlier versions read as the unions they always meant (SUPPORT_GROUPS):
torso = upper_back + lower_back + pelvis, arms = upper_arms + forearms, legs = thighs + calves.
A use (SUPPORT_USES) names the regions a kind of furniture carries, so a scenario can say
`support = "chair"`; `support_regions` expands any mix of these names to regions.

This module imports nothing, so that `sitrelax --help` can list the names without loading
numpy or h5py.
"""

from __future__ import annotations

BODY_REGIONS = ("head", "upper_back", "lower_back", "pelvis", "thighs", "calves", "feet",
                "upper_arms", "forearms", "hands")

# the coarse body parts earlier scenario files and pose libraries name
SUPPORT_GROUPS = {
    "torso": ("upper_back", "lower_back", "pelvis"),
    "arms": ("upper_arms", "forearms"),
    "legs": ("thighs", "calves"),
}

_BACK = ("upper_back", "lower_back")
# the regions each use of a surface supports; the calves hang off every use but the bed and
# the floor cushion (a sheet drawn down behind hanging calves folds and loads them)
SUPPORT_USES = {
    "seat": ("pelvis", "thighs"),                 # a bench or seat without a back
    "stool": ("pelvis",),                         # a perch: the thighs slope off its edge
    "chair": _BACK + ("pelvis", "thighs"),        # a seat with a backrest
    "lounger": ("head",) + _BACK + ("pelvis", "thighs"),  # reclined, knees bent
    "bed": ("head", "upper_arms") + _BACK + ("pelvis", "thighs", "calves", "feet"),  # all
    # but the forearms and hands, which move freely in bed (a raised hand pulled a 0.3 m hump
    # out of the mattress); the upper arms of a person lying on the back lie on it
    "floor": ("pelvis", "thighs", "calves", "feet"),  # a floor cushion: legs on it too
}
DEFAULT_SUPPORT = "seat"  # what a person of a scenario or a new pose needs supported, unless told

SUPPORT_NAMES = BODY_REGIONS + tuple(SUPPORT_GROUPS) + tuple(SUPPORT_USES)


class SupportNameError(ValueError):
    """A support that names something other than a body region, group or use."""


def support_regions(names) -> tuple[str, ...]:
    """The body regions that a support names, in BODY_REGIONS order.

    Parameters
    ----------
    names : str or iterable of str
        One name or several, each a region (BODY_REGIONS), a coarse part (SUPPORT_GROUPS:
        torso, arms, legs) or a use (SUPPORT_USES: seat, chair, ...); case and surrounding
        spaces do not matter.

    Returns
    -------
    tuple of str
        The regions the names cover together, each once, in BODY_REGIONS order.

    Raises
    ------
    SupportNameError
        If a name is none of those, or no name is given.
    """
    if isinstance(names, str):
        names = (names,)
    try:
        names = list(names)
    except TypeError:
        raise SupportNameError(f"Expected a body region, a use or a list of regions, got "
                               f"{names!r}") from None
    if not names:
        raise SupportNameError(f"Expected at least one body region or a use, got {names!r}")
    wanted = set()
    for name in names:
        key = name.strip().lower() if isinstance(name, str) else None  # None: no name at all
        if key in SUPPORT_USES:
            wanted.update(SUPPORT_USES[key])
        elif key in SUPPORT_GROUPS:
            wanted.update(SUPPORT_GROUPS[key])
        elif key in BODY_REGIONS:
            wanted.add(key)
        else:
            raise SupportNameError(
                f"Expected body regions ({', '.join(BODY_REGIONS)}), parts "
                f"({', '.join(SUPPORT_GROUPS)}) or uses ({', '.join(SUPPORT_USES)}), "
                f"got {name!r}")
    return tuple(r for r in BODY_REGIONS if r in wanted)
