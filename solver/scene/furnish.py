"""A furniture template fitted around posed people: the dimensions a scenario leaves unset, and
where the template stands, measured on the people's skin and joints.

The people are placed (`solver.scene.placement.place_person`: metres, Y up, the floor y = 0).
The template's heading is the people's mean forward direction (the hips' left-to-right axis
turned a quarter about +y; for a lying person, towards the feet); the measurements are taken in
the template's own frame (`solver.surface.templates`: width along x, front towards +z). Every
surface starts `CLEARANCE` below or behind the skin it is to support: the fit then lifts it
into contact (it may sink up to its margin into the skin), so it never starts inside a body.

    chair, bench   seat height just under the buttocks and thighs over the seat, tilted along
                   them; rear line behind the buttocks and the back; depth to a hand's width
                   short of the knee pits; width over every sitter's hips and thighs plus
                   SIDE_MARGIN each side; the back leaning as the trunk (hips to neck), behind
                   the back's skin, up to the shoulder blades; arms (if asked for) under the
                   elbows; a bench has a seat per sitter; asked for (`furnish`'s
                   `waterfall`), a front edge rounded down where calves tuck under it
    stool          the seat under the buttocks, centred on them
    floor_cushion  under the buttocks, thighs and feet of a floor sitter; its back (if asked
                   for) as a chair's
    lounger        seat hollow under the buttocks, knee crest under the knees, foot rest to
                   the heels, back as long as hips to the top of the head, reclined as the trunk
    bed            under the whole lying body (all sleepers), with BED_MARGIN around it

Explicit parameters override what is measured (and the other measurements use them: a given
seat height places the back's foot there). People on the floor who need a surface under them
(lying, floor sitting) must be lifted first (their scenario `position` y): the template cannot
go below the floor, and `TemplateError` says so.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from solver.body.model import BODY_REGIONS
from solver.surface.templates import (TEMPLATE_PARAMS, TemplateError, TemplateMesh,
                                      edge_drop_limit, make_template)

CLEARANCE = 0.01  # metres between the starting surface and the skin it supports
SIDE_MARGIN = 0.04  # metres of seat beyond the outermost hip or thigh, each side
KNEE_PIT = 0.11  # metres from the knee joint back to where a seat's front edge ends
WATERFALL = 0.08  # metres a chair's or bench's front edge drops where calves tuck under it
BED_MARGIN = 0.08  # metres of bed around a lying body
MIN_DEPTH = 0.2  # metres: no stool seat shallower
MIN_TOP = 0.03  # metres: a cushion or bed top lower than this is no furniture


def person_joints(person) -> np.ndarray:
    """(J, 3) a placed person's rig joints in the scene (metres): the posed rig moved by the
    person's placement (`PlacedPerson.transform`)."""
    t = person.transform
    return person.motion.world.positions[0] @ t[:3, :3].T + t[:3, 3]


def _region_mask(person, *names: str) -> np.ndarray:
    wanted = [BODY_REGIONS.index(n) for n in names if n in BODY_REGIONS]
    return np.isin(person.body.regions, wanted)


class _Local:
    """The people in the template's frame: turned by -heading about +y (the front to +z)."""

    def __init__(self, heading_deg: float):
        a = math.radians(heading_deg)
        c, s = math.cos(a), math.sin(a)
        self.heading_deg = heading_deg
        self.rot = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])  # local -> scene

    def points(self, p: np.ndarray) -> np.ndarray:
        return np.asarray(p) @ self.rot  # scene -> local (rot is orthonormal)

    def position(self, x: float, z: float) -> tuple[float, float]:
        """The scene (x, z) of a local floor point."""
        s = self.rot @ [x, 0.0, z]
        return float(s[0]), float(s[2])


def _forward(person, lying: bool) -> np.ndarray:
    """(3,) a person's forward direction on the floor: the hips' left axis turned a quarter
    (standing, sitting; a supine body's feet); for a body on its side, head to ankles."""
    names = person.body.joint_names
    j = person_joints(person)
    left = j[names.index("LeftUpLeg")] - j[names.index("RightUpLeg")]
    forward = np.cross(left, [0.0, 1.0, 0.0])
    forward[1] = 0.0
    if np.linalg.norm(forward) < 0.3 * np.linalg.norm(left) or lying and \
            np.linalg.norm(forward) < 1e-9:
        feet = (j[names.index("LeftFoot")] + j[names.index("RightFoot")]) / 2
        forward = feet - j[names.index("Head")]
        forward[1] = 0.0
    norm = np.linalg.norm(forward)
    if norm < 1e-9:
        raise TemplateError(f"{person.label}: no forward direction to set a template by")
    return forward / norm


def people_heading(people: Sequence, lying: bool = False) -> float:
    """The template's heading (degrees about +y, 0: its front to +z) from the people's mean
    forward direction."""
    f = np.sum([_forward(p, lying) for p in people], axis=0)
    if np.linalg.norm(f) < 1e-6:
        raise TemplateError("The people face opposite ways: give the template's heading_deg")
    return float(np.degrees(np.arctan2(f[0], f[2])))


def furnish(kind: str, given: dict, people: Sequence, *, waterfall: bool = False
            ) -> TemplateMesh:
    """The template of `kind` around the people: the parameters in `given` as they are, the
    rest measured on the people (see the module docstring).

    Parameters
    ----------
    kind : a template kind (`solver.surface.templates.KINDS`).
    given : parameter name -> value, those the scenario sets (lists for tuples).
    people : the placed people (`PlacedPerson`: skin vertices (V, 3) metres, body regions, the
        posed rig and its placement).
    waterfall : a chair's or bench's `front_drop`, when not given, measured too: WATERFALL
        (at most a quarter of the seat's depth) where calves tucked under the seat come nearer
        its front edge than the fit's rim clearance, else none. It adds a row of quads, so a
        scenario's template never gets it (its topology is read before the people are
        placed): `sitrelax design` asks for it and writes the drop into the scenario.

    Returns
    -------
    TemplateMesh, in the scene. Raises TemplateError for a kind or parameter that makes no
    furniture, or people a template cannot stand under.
    """
    if kind not in TEMPLATE_PARAMS:
        raise TemplateError(f"Expected a template kind of {list(TEMPLATE_PARAMS)}, got {kind!r}")
    if not people:
        raise TemplateError("Expected at least one person to fit a template around, got none")
    given = {k: tuple(v) if isinstance(v, list) else v for k, v in given.items()
             if v is not None}
    lying = kind == "bed"
    frame = _Local(given["heading_deg"] if "heading_deg" in given
                   else people_heading(people, lying))
    measure = {"chair": _seat_measures, "bench": _seat_measures, "stool": _stool_measures,
               "floor_cushion": _cushion_measures, "lounger": _lounger_measures,
               "bed": _bed_measures}[kind]
    values = measure(kind, given, people, frame, waterfall) if measure is _seat_measures \
        else measure(kind, given, people, frame)
    values = {k: float(v) if isinstance(v, (float, np.floating)) else v
              for k, v in values.items()}
    measured = set(values) - set(given)
    values.update(given)
    values["heading_deg"] = frame.heading_deg
    limit = None if "edge_drop" in given else edge_drop_limit(kind, values)
    if limit is not None and 0 < limit < values.get("edge_drop", TEMPLATE_PARAMS[kind].edge_drop):
        # a top measured low: its edges rounded down by as much as its corners allow (not to
        # nothing: an unrounded top has other faces, so a drop its corners allow none of is
        # refused by name)
        values["edge_drop"] = limit
        measured.add("edge_drop")
    try:
        return make_template(kind, **values)
    except TemplateError as exc:
        exc.measured = measured  # (what the scenario's error may blame on the people)
        raise


# measurements -------------------------------------------------------------------------------

class _Skin:
    """The people's skin and joints in the template's frame, by region."""

    def __init__(self, people: Sequence, frame: _Local):
        self.people = people
        self.frame = frame
        self.points = [frame.points(p.vertices) for p in people]
        self.joints = [frame.points(person_joints(p)) for p in people]

    def region(self, *names: str) -> np.ndarray:
        """(N, 3) local points of the named regions of everybody."""
        return np.concatenate([pts[_region_mask(p, *names)]
                               for p, pts in zip(self.people, self.points)])

    def joint(self, name: str) -> np.ndarray:
        """(P, 3) a joint's local position per person."""
        return np.stack([j[p.body.joint_names.index(name)]
                         for p, j in zip(self.people, self.joints)])

    def pair(self, left: str, right: str) -> np.ndarray:
        """(P, 3) the middle of a left and right joint per person."""
        return (self.joint(left) + self.joint(right)) / 2


def _under(points: np.ndarray, z0: float, z1: float, half: float, x0: float) -> np.ndarray:
    """The points over a footprint: z in [z0, z1], |x - x0| <= half."""
    keep = (points[:, 2] >= z0) & (points[:, 2] <= z1) & (np.abs(points[:, 0] - x0) <= half)
    return points[keep]


def _width(seat: np.ndarray) -> tuple[float, float]:
    """(middle x, width) over the seat points, with the side margins."""
    lo, hi = seat[:, 0].min() - SIDE_MARGIN, seat[:, 0].max() + SIDE_MARGIN
    return float((lo + hi) / 2), float(hi - lo)


def _calves_front(skin: _Skin, seat: np.ndarray, x0: float, half: float) -> float:
    """The z where a seat under the `seat` points must end to keep its rim clear of the
    calves: the rearmost calf skin over the seat's width that lies in the seat's foam or just
    above it (within the fit's RIM_SLAB below the lowest seat point and RIM_FRONT above it),
    less the rim's clearance there (`solver.surface.fit.RIM_CLEARANCE`, and RIM_SLANT of
    how far below the seat's top the skin lies); inf without such calves."""
    from solver.surface.fit import RIM_CLEARANCE, RIM_FRONT, RIM_SLAB, RIM_SLANT

    top = float(seat[:, 1].min())
    calves = skin.region("calves")
    near = calves[(calves[:, 1] >= top - RIM_SLAB) & (calves[:, 1] <= top + RIM_FRONT) &
                  (np.abs(calves[:, 0] - x0) <= half)]
    if not len(near):
        return math.inf
    return float(np.min(near[:, 2] - RIM_CLEARANCE - RIM_SLANT * np.maximum(top - near[:, 1],
                                                                            0.0)))


def _trunk_angle(skin: _Skin) -> float:
    """Degrees from vertical the trunks lean back (hips' middle to neck, mean over people)."""
    trunk = skin.joint("Neck") - skin.pair("LeftUpLeg", "RightUpLeg")
    return float(np.degrees(np.arctan2(-trunk[:, 2], trunk[:, 1])).mean())


def _seat_plane(seat: np.ndarray, z_rear: float, z_front: float, half: float, x0: float,
                tilt_deg: float | None, height: float | None) -> tuple[float, float]:
    """(front height, tilt in degrees) of a seat plane under the seat points over the
    footprint, CLEARANCE below the lowest; the tilt follows the buttocks and thighs (the
    lowest point of the rear and front thirds) unless given."""
    over = _under(seat, z_rear, z_front, half, x0)
    if not len(over):
        raise TemplateError("No buttocks or thighs over the seat to measure its height by")
    depth = z_front - z_rear
    if tilt_deg is None:
        rear = over[over[:, 2] <= z_rear + depth / 3, 1]
        front = over[over[:, 2] >= z_front - depth / 3, 1]
        tilt_deg = 0.0 if not (len(rear) and len(front)) else float(np.clip(np.degrees(
            np.arctan2(front.min() - rear.min(), 2 * depth / 3)), -15.0, 15.0))
    slope = math.tan(math.radians(tilt_deg))
    if height is None:
        plane = over[:, 1] + (z_front - over[:, 2]) * slope  # each point's front height
        height = float(plane.min()) - CLEARANCE
    return height, tilt_deg


def _back_line(skin: _Skin, z_rear: float, seat_y: float, angle_deg: float, top: float,
               half: float, x0: float) -> float:
    """The z where a back leaning `angle_deg` from vertical meets the seat (at height seat_y)
    so that the back's skin up to `top` stays CLEARANCE in front of it; no further forward
    than z_rear."""
    back = skin.region("pelvis", "lower_back", "upper_back", "shoulders")
    back = back[(back[:, 1] >= seat_y) & (back[:, 1] <= top) &
                (np.abs(back[:, 0] - x0) <= half)]
    lean = math.tan(math.radians(angle_deg))
    if not len(back):
        return z_rear
    return float(min(z_rear, (back[:, 2] + (back[:, 1] - seat_y) * lean).min() - CLEARANCE))


def _seat_measures(kind: str, given: dict, people: Sequence, frame: _Local,
                   waterfall: bool = False) -> dict:
    if kind == "bench" and given.get("seat_each") and "seat_profiles" not in given:
        return _seat_each_measures(given, people, frame, waterfall)
    skin = _Skin(people, frame)
    defaults = TEMPLATE_PARAMS[kind]()
    seat = skin.region("pelvis", "thighs")
    x0, width = _width(seat)
    seats = given.get("seats", len(people)) if kind == "bench" else 1
    if "seat_width" in given:
        width = given["seat_width"] * seats
    half = width / 2
    z_rear = float(seat[:, 2].min()) - CLEARANCE
    z_front = float(skin.pair("LeftLeg", "RightLeg")[:, 2].min()) - KNEE_PIT
    back = given.get("back", defaults.back if kind != "chair" else True)
    angle = given.get("back_angle_deg", float(np.clip(_trunk_angle(skin), 0.0, 40.0)))
    neck = float(skin.joint("Neck")[:, 1].min())
    height, tilt = _seat_plane(seat, z_rear, z_front, half, x0, given.get("seat_tilt_deg"),
                               given.get("seat_height"))
    if back:
        rear_y = height - (z_front - z_rear) * math.tan(math.radians(tilt))
        z_rear = _back_line(skin, z_rear, rear_y, angle, neck - 0.08, half, x0)
    if "seat_depth" in given:
        z_front = z_rear + given["seat_depth"]
        height, tilt = _seat_plane(seat, z_rear, z_front, half, x0, given.get(
            "seat_tilt_deg", tilt), given.get("seat_height"))
    out = {"seat_height": height, "seat_tilt_deg": tilt, "seat_depth": z_front - z_rear,
           "seat_width": width / seats, "back": back, "back_angle_deg": angle,
           "position": frame.position(x0, z_rear)}
    if waterfall and "front_drop" not in given and \
            _calves_front(skin, _under(seat, z_rear, z_front, half, x0), x0, half) < z_front:
        # calves tucked under the seat would meet its front edge: a waterfall front (8 cm, at
        # most a quarter of the depth) takes the edge down and away from them
        out["front_drop"] = min(WATERFALL, (z_front - z_rear) / 4)
    if kind == "bench":
        out["seats"] = seats
    rear_y = height - (z_front - z_rear) * math.tan(math.radians(tilt))
    if back:
        out["back_height"] = float(max(neck - 0.08 - rear_y, 0.15)) / \
            math.cos(math.radians(angle))
    if given.get("arms"):
        elbows = np.concatenate([skin.joint("LeftForeArm"), skin.joint("RightForeArm")])
        out["arm_height"] = float(np.clip(elbows[:, 1].min() - 0.05 - height, 0.1, 0.4))
    return out


SEAT_OWN = ("seat_height", "seat_depth", "seat_tilt_deg", "back_angle_deg", "back_height")


def _seat_each_measures(given: dict, people: Sequence, frame: _Local, waterfall: bool
                        ) -> dict:
    """A bench with a seat each (`BenchParams.seat_each`): the bench's measures for them all,
    then each sitter's seat measured as a chair of their own (its height, depth, tilt and
    back, the given ones as they are), side by side from -x to +x, each as wide as the sitter's
    chair up to the seams, halfway between neighbouring chairs' edges; the bench's rear line
    the rearmost seat's, its front edge dropped (a waterfall) if any seat's is."""
    if given.get("seats", len(people)) != len(people):
        raise TemplateError(f"bench.seat_each: a seat each needs a seat per sitter, got seats = "
                            f"{given['seats']} for {len(people)} people")
    common = _seat_measures("bench", {k: v for k, v in given.items() if k != "seat_each"},
                            people, frame, waterfall)
    own = {**{k: v for k, v in given.items() if k in SEAT_OWN + ("front_drop",)},
           "back": common["back"]}  # (a chair's back is the bench's: none on a backless one)
    order = sorted(people, key=lambda p: float(np.mean(frame.points(p.vertices)[:, 0])))
    seats = [_seat_measures("chair", own, [p], frame, waterfall) for p in order]
    local = [frame.points(np.array([[s["position"][0], 0.0, s["position"][1]]]))[0]
             for s in seats]
    x0, z_rear = np.array([p[0] for p in local]), np.array([p[2] for p in local])
    half = np.array([s["seat_width"] for s in seats]) / 2
    bounds = np.concatenate([[x0[0] - half[0]], ((x0 + half)[:-1] + (x0 - half)[1:]) / 2,
                             [x0[-1] + half[-1]]])
    widths = np.diff(bounds)
    if np.any(widths < 0.1):
        raise TemplateError("bench.seat_each: the sitters overlap too far for a seat each "
                            "(set them further apart)")
    ref = float(z_rear.min())
    common["seat_profiles"] = tuple(
        {**{k: float(s[k]) for k in SEAT_OWN if k in s}, "seat_width": float(w),
         "rear": float(z - ref)} for s, w, z in zip(seats, widths, z_rear))
    common["seat_width"] = float(widths.mean())
    common["front_drop"] = max(float(s.get("front_drop", 0.0)) for s in seats)
    common["position"] = frame.position(float(bounds[0] + bounds[-1]) / 2, ref)
    return common


def _stool_measures(kind: str, given: dict, people: Sequence, frame: _Local) -> dict:
    skin = _Skin(people, frame)
    seat = skin.region("pelvis", "thighs")
    x0, width = _width(skin.region("pelvis"))
    width = given.get("seat_width", width)
    depth = given.get("seat_depth", TEMPLATE_PARAMS[kind]().seat_depth)
    buttocks = skin.region("pelvis")
    z_mid = float(buttocks[np.argmin(buttocks[:, 1]), 2]) + 0.04
    if "seat_depth" not in given:  # the front stops short of calves tucked under the seat
        front = min(z_mid + depth / 2, _calves_front(skin, seat, x0, width / 2))
        depth = max(front - (z_mid - depth / 2), MIN_DEPTH)
        z_mid = front - depth / 2
    height, tilt = _seat_plane(seat, z_mid - depth / 2, z_mid + depth / 2, width / 2, x0,
                               given.get("seat_tilt_deg"), given.get("seat_height"))
    return {"seat_height": height, "seat_tilt_deg": tilt, "seat_width": width,
            "seat_depth": depth, "position": frame.position(x0, z_mid)}


def _top_height(points: np.ndarray, what: str) -> float:
    top = float(points[:, 1].min()) - CLEARANCE
    if top < MIN_TOP:
        raise TemplateError(
            f"The people's lowest point is {top + CLEARANCE:.3f} m above the floor, leaving "
            f"no room for a {what} under them: lift them (each person's position y, e.g. "
            f"0.45 for a bed, 0.13 for a floor cushion) or give its height")
    return top


def _cushion_measures(kind: str, given: dict, people: Sequence, frame: _Local) -> dict:
    skin = _Skin(people, frame)
    seat = skin.region("pelvis", "thighs")
    under = skin.region("pelvis", "thighs", "calves", "feet")
    x0, width = _width(skin.region("pelvis", "thighs", "calves", "feet"))
    z_rear = float(seat[:, 2].min()) - CLEARANCE
    z_front = float(under[:, 2].max()) + CLEARANCE
    width = given.get("width", width)
    back = given.get("back", False)
    height = given.get("height")
    if height is None:
        height = _top_height(_under(under, z_rear, z_front, width / 2, x0), "floor cushion")
    out = {"height": height, "width": width, "back": back}
    angle = given.get("back_angle_deg", float(np.clip(_trunk_angle(skin), 0.0, 60.0)))
    if back:
        neck = float(skin.joint("Neck")[:, 1].min())
        z_rear = _back_line(skin, z_rear, height, angle, neck - 0.08, width / 2, x0)
        out.update(back_angle_deg=angle, back_height=float(max(neck - 0.08 - height, 0.15))
                   / math.cos(math.radians(angle)))
    out.update(depth=given.get("depth", z_front - z_rear),
               position=frame.position(x0, z_rear))
    return out


def _lounger_measures(kind: str, given: dict, people: Sequence, frame: _Local) -> dict:
    skin = _Skin(people, frame)
    x0, width = _width(skin.region("pelvis", "thighs", "upper_back", "lower_back"))
    buttocks = skin.region("pelvis")
    low = buttocks[np.argmin(buttocks[:, 1])]
    z0 = float(low[2])
    trunk = float(np.clip(_trunk_angle(skin), 10.0, 85.0))
    angle = given.get("back_angle_deg", trunk)
    legs = skin.region("thighs", "calves", "feet")
    knee = skin.pair("LeftLeg", "RightLeg")
    z_knee = float(knee[:, 2].mean())
    near_knee = legs[np.abs(legs[:, 2] - z_knee) <= 0.05]
    seat_height = given.get("seat_height", float(low[1]) - CLEARANCE)
    knee_height = given.get("knee_height", float(near_knee[:, 1].min()) - CLEARANCE
                            if len(near_knee) else seat_height + 0.1)
    thigh = given.get("thigh_length", math.hypot(z_knee - z0, knee_height - seat_height))
    ankle = skin.pair("LeftFoot", "RightFoot")
    z_foot = float(ankle[:, 2].max()) + 0.06
    near_foot = legs[np.abs(legs[:, 2] - z_foot + 0.06) <= 0.06]
    foot_height = given.get("foot_height", max(float(near_foot[:, 1].min()) - CLEARANCE, 0.05)
                            if len(near_foot) else knee_height)
    leg = given.get("leg_length", math.hypot(z_foot - z_knee, knee_height - foot_height) + 0.02)
    head = skin.region("head")
    top = float(np.hypot(head[:, 2] - z0, head[:, 1] - seat_height).max())
    out = {"seat_height": seat_height, "knee_height": knee_height, "thigh_length": thigh,
           "foot_height": foot_height, "leg_length": leg, "back_angle_deg": angle,
           "back_length": given.get("back_length", top + 0.05), "width": width,
           "position": frame.position(x0, z0)}
    # the back behind the back's skin: lower the whole chaise where the skin comes closer
    a = math.radians(angle)
    normal = np.array([math.cos(a), math.sin(a)])  # (z, y) of the back's normal, forward-up
    back = skin.region("lower_back", "upper_back", "shoulders", "head")
    ahead = (back[:, 2] - z0) * normal[0] + (back[:, 1] - seat_height) * normal[1]
    short = CLEARANCE - float(ahead.min()) if len(back) else 0.0
    if short > 0 and "seat_height" not in given:
        drop = short / normal[1]
        out["seat_height"] -= drop
        out["knee_height"] = out["knee_height"] - drop if "knee_height" not in given \
            else out["knee_height"]
    return out


def _bed_measures(kind: str, given: dict, people: Sequence, frame: _Local) -> dict:
    skin = _Skin(people, frame)
    every = np.concatenate(skin.points)
    lo, hi = every.min(axis=0), every.max(axis=0)
    width = given.get("width", float(hi[0] - lo[0]) + 2 * BED_MARGIN)
    length = given.get("length", float(hi[2] - lo[2]) + 2 * BED_MARGIN)
    x0, z0 = float(lo[0] + hi[0]) / 2, float(lo[2] + hi[2]) / 2
    height = given.get("height")
    if height is None:
        height = _top_height(every, "bed")
    return {"height": height, "width": width, "length": length,
            "position": frame.position(x0, z0)}
